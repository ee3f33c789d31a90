// `svo bench store STORE_OR_MESH`: the slice store's I/O, measured against peers in the same run:
//   - slice read + XXH3 verify + zstd decode (StoreReader::readSlice, warm page cache) against plain
//     ZSTD_decompress of the same compressed bytes already in memory;
//   - random-order slice reads from a cold file, by one reader and by --read-threads concurrent readers (as
//     the pager's workers read), whole readSlice and bare pread, against the sequential bandwidth
//     `dd bs=1M` gets from the same cold file (the page cache is dropped with
//     posix_fadvise(POSIX_FADV_DONTNEED) before every run); the goal is judged on readSlice with readers;
//   - bytes per leaf voxel on disk, per part and attachment (the accounting `svo inspect` uses);
//   - what a load costs per voxel, stage by stage on one thread, against the pager's goal, and the pool's
//     laid-out blocks stored as they are instead: their bytes on disk and their decompression
//     (bench_store_load.cpp);
//   - given a mesh: the in-core build (buildOctree + writeOctree) on 1 and 2 threads, triangles/s, voxels/s
//     and peak RSS, against OpenVDB meshToLevelSet at the same resolution (bench_build.cpp's peer).
#include <fcntl.h>
#include <sys/mman.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <fstream>
#include <functional>
#include <numeric>
#include <optional>
#include <random>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <tbb/global_control.h>
#include <zstd.h>

#include "bench_common.hpp"
#include "bench_store_load.hpp"
#include "machine.hpp"
#include "process.hpp"
#include "store_stats.hpp"
#include "svo/builder/build.hpp"
#include "svo/store/format.hpp"
#include "svo/store/store_reader.hpp"
#include "svo/store/store_writer.hpp"

namespace svo::tools::bench {

namespace {

// Thread counts of the build comparison: 1 and 2.
constexpr int kBuildThreads[] = {1, 2};
// A timed sample repeats a warm pass until it lasts this long: timer resolution and scheduler noise then
// stay around 1% even for a store of a few slices.
constexpr double kMinSampleSeconds = 0.2;
// Fixed seed of the random slice order: the same order in every run and every invocation.
constexpr std::uint64_t kShuffleSeed = 0x5EED;
// Goals of the slice store, printed next to the measured ratios.
constexpr double kDecodeGoal = 0.8, kColdReadGoal = 0.5;
// Slice size goals: median at least half the target, none above 1.5x it unless its cube cannot split.
constexpr double kMedianSliceGoal = 0.5, kLargestSliceGoal = 1.5;
// Compressed bytes the warm comparison keeps in memory: the first slices up to this much (all of a small
// store), so that a store of any size is measured in bounded memory.
constexpr std::uint64_t kWarmSampleBytes = std::uint64_t(256) << 20;

struct StoreArgs {
  std::string input, store;
  int levels = 10;
  int runs = 3;
  int readThreads = 4;
};

double megabytesPerSecond(double bytes, double seconds) {
  return seconds > 0.0 ? bytes / seconds * 1e-6 : 0.0;
}
std::string mbs(double bytes, double seconds) {
  return fmt::format("{:.1f}", megabytesPerSecond(bytes, seconds));
}
std::string mib(double bytes) {
  return fmt::format("{:.1f}", bytes / double(1 << 20));
}

// Two methods timed in alternation, so that load from other processes falls on both alike: one warm-up pass
// of each decides how many passes make a sample of at least kMinSampleSeconds, then `runs` samples of A and B
// in turn. Seconds per pass, and the median of the per-sample ratios B / A (a's speed relative to b's).
struct Paired {
  Summary a, b;
  double ratio = 0.0;
};
template <class A, class B>
Paired timePaired(int runs, A&& passA, B&& passB) {
  const auto repeats = [](double warm) {
    return std::max(1, int(std::ceil(kMinSampleSeconds / std::max(warm, 1e-9))));
  };
  const int repeatA = repeats(timeSeconds(passA)), repeatB = repeats(timeSeconds(passB));
  const auto sample = [](auto& pass, int repeat) {
    return timeSeconds([&] {
             for (int k = 0; k < repeat; ++k) pass();
           }) /
           repeat;
  };
  std::vector<double> a, b, ratios;
  for (int i = 0; i < runs; ++i) {
    a.push_back(sample(passA, repeatA));
    b.push_back(sample(passB, repeatB));
    ratios.push_back(b.back() / a.back());
  }
  return {summarize(std::move(a)), summarize(std::move(b)), summarize(std::move(ratios)).median};
}

// A store by its magic, or by its name: a damaged .svo then gets the store reader's error, not the mesh
// loader's.
bool isStore(const std::filesystem::path& path) {
  if (path.extension() == ".svo") return true;
  char magic[sizeof kFileMagic] = {};
  std::ifstream in(path, std::ios::binary);
  return in.read(magic, sizeof magic) && std::memcmp(magic, kFileMagic, sizeof magic) == 0;
}

// ----- peak resident memory --------------------------------------------------------------------------------

// Resets the kernel's peak-RSS mark (Linux >= 4.0: "5" to /proc/self/clear_refs). False when refused: the
// peaks measured afterwards are then the process's peak so far.
bool resetPeakRss() {
  std::ofstream clear("/proc/self/clear_refs");
  return clear && (clear << "5").flush().good();
}

// ----- the page cache of one file --------------------------------------------------------------------------

class CachedFile {
 public:
  explicit CachedFile(const std::filesystem::path& path) : path_(path), fd_(::open(path.c_str(), O_RDONLY)) {
    if (fd_ < 0) throw std::runtime_error(path.string() + ": cannot open (" + std::strerror(errno) + ")");
    struct stat st {};
    ::fstat(fd_, &st);
    bytes_ = std::uint64_t(st.st_size);
  }
  ~CachedFile() { ::close(fd_); }
  CachedFile(const CachedFile&) = delete;
  CachedFile& operator=(const CachedFile&) = delete;

  std::uint64_t bytes() const { return bytes_; }
  int fd() const { return fd_; }
  // Writes back anything dirty, then asks the kernel to drop the file's cached pages.
  void drop() const {
    ::fdatasync(fd_);
    ::posix_fadvise(fd_, 0, 0, POSIX_FADV_DONTNEED);
  }
  // Fraction of the file's pages in the page cache (mincore), to show that drop() worked.
  double resident() const {
    if (bytes_ == 0) return 0.0;
    void* map = ::mmap(nullptr, bytes_, PROT_READ, MAP_SHARED, fd_, 0);
    if (map == MAP_FAILED) return -1.0;
    const std::size_t page = std::size_t(::sysconf(_SC_PAGESIZE));
    std::vector<unsigned char> pages((bytes_ + page - 1) / page);
    const bool ok = ::mincore(map, bytes_, pages.data()) == 0;
    ::munmap(map, bytes_);
    if (!ok) return -1.0;
    const auto in = std::count_if(pages.begin(), pages.end(), [](unsigned char p) { return p & 1u; });
    return double(in) / double(pages.size());
  }

 private:
  std::filesystem::path path_;
  int fd_;
  std::uint64_t bytes_ = 0;
};

// Seconds to run `read(id)` for every id of `order`, `threads` workers taking the next id in turn: the
// reads a pager's workers keep in flight at once (the disk sees that queue depth).
template <class Read>
double timeConcurrentReads(const std::vector<std::uint32_t>& order, int threads, Read&& read) {
  std::atomic<std::size_t> next{0};
  return timeSeconds([&] {
    std::vector<std::jthread> workers;
    for (int i = 0; i < threads; ++i)
      workers.emplace_back([&] {
        for (std::size_t k; (k = next.fetch_add(1)) < order.size();) read(order[k]);
      });
  });
}

// `dd if=FILE of=/dev/null bs=1M` with LC_ALL=C; dd's own byte count and seconds from its last line
// ("N bytes (...) copied, T s, R MB/s"). nullopt when dd cannot be run or says something else.
struct DdResult {
  std::uint64_t bytes = 0;
  double seconds = 0.0;
};
std::optional<DdResult> runDd(const std::filesystem::path& file) {
  const std::optional<ProcessResult> dd = runProcess({"dd", "if=" + file.string(), "of=/dev/null", "bs=1M"},
                                                     {.workingDirectory = {}, .cLocale = true});
  if (!dd || !dd->succeeded()) return std::nullopt;
  const std::string& output = dd->output;
  const std::size_t line = output.rfind(" bytes");
  const std::size_t copied = output.find("copied, ", line == std::string::npos ? 0 : line);
  if (line == std::string::npos || copied == std::string::npos) return std::nullopt;
  const std::size_t lineStart = output.rfind('\n', line);
  DdResult r;
  try {
    r.bytes = std::stoull(output.substr(lineStart == std::string::npos ? 0 : lineStart + 1));
    r.seconds = std::stod(output.substr(copied + 8));
  } catch (const std::exception&) {
    return std::nullopt;
  }
  return r.seconds > 0.0 ? std::optional(r) : std::nullopt;
}

// ----- the build comparison --------------------------------------------------------------------------------

struct BuildRow {
  std::string method;
  int threads = 0;
  Summary seconds;
  std::uint64_t voxels = 0;  // all levels (ESVO) or active voxels (OpenVDB)
  std::uint64_t peakRss = 0;
};

void benchBuild(const StoreArgs& args, const std::filesystem::path& storePath) {
  const Mesh mesh = loadBenchMesh(args.input);
  const SceneTransform scene = fitSceneCube(mesh);
  BuildOptions options;
  options.levels = args.levels;
  const std::int64_t resolution = std::int64_t(1) << args.levels;
  const bool peaksReset = resetPeakRss();
  std::vector<BuildRow> rows;
  std::vector<std::size_t> hashes;
  double writeSeconds = 0.0;
  for (const int threads : kBuildThreads) {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
    spdlog::info("ESVO buildOctree, {} levels, {} thread(s), {} runs ...", args.levels, threads, args.runs);
    resetPeakRss();
    Octree octree;
    BuildStats stats;
    std::vector<double> samples;
    for (int i = 0; i < args.runs; ++i) {
      octree = Octree{};  // the previous run's octree is gone before the next build starts
      stats = {};
      samples.push_back(timeSeconds([&] { octree = buildOctree(mesh, options, &stats); }));
    }
    const std::uint64_t voxels =
        std::accumulate(stats.voxelsPerLevel.begin(), stats.voxelsPerLevel.end(), std::uint64_t(0));
    rows.push_back({"ESVO buildOctree", threads, summarize(std::move(samples)), voxels, peakResidentBytes()});
    const AlignedBytes& bytes = octree.block.bytes();
    hashes.push_back(std::hash<std::string_view>{}(
        std::string_view(reinterpret_cast<const char*>(bytes.data()), bytes.size())));
    if (threads == kBuildThreads[std::size(kBuildThreads) - 1])
      writeSeconds = timeSeconds([&] { writeOctree(storePath, octree); });
  }
  for (const int threads : kBuildThreads) {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
    spdlog::info("OpenVDB meshToLevelSet {}^3, {} thread(s), {} runs ...", resolution, threads, args.runs);
    resetPeakRss();
    const std::optional<LevelSetResult> peer =
        openVdbLevelSet(mesh, scene.origin, scene.size / double(resolution), args.runs);
    if (peer)
      rows.push_back(
          {"OpenVDB meshToLevelSet", threads, peer->seconds, peer->activeVoxels, peakResidentBytes()});
  }

  printTitle("Building in core: ESVO octree vs OpenVDB level set, same triangles, same resolution");
  fmt::print("{}: {} triangles; {} levels = {}^3; median of {} runs; store written in {}\n", args.input,
             formatCount(mesh.triangles.size()), args.levels, resolution, args.runs,
             formatSeconds(writeSeconds));
  Table table({"method", "threads", "time", "Mtriangles/s", "Mvoxels/s", "voxels", "peak RSS MiB", "vs VDB"});
  for (const BuildRow& row : rows) {
    const auto peer = std::find_if(rows.begin(), rows.end(), [&](const BuildRow& r) {
      return r.method != row.method && r.threads == row.threads && row.method.starts_with("ESVO");
    });
    const double t = row.seconds.median;
    table.addRow({row.method, std::to_string(row.threads), formatSeconds(t),
                  fmt::format("{:.3g}", double(mesh.triangles.size()) / t * 1e-6),
                  fmt::format("{:.3g}", double(row.voxels) / t * 1e-6), formatCount(row.voxels),
                  mib(double(row.peakRss)),
                  peer != rows.end()               ? fmt::format("{:.2f}x", peer->seconds.median / t)
                  : row.method.starts_with("ESVO") ? std::string(kPeerNotBuilt)
                                                   : std::string("-")});
  }
  table.print();
  fmt::print(
      "ESVO: svo::buildOctree (voxelize with contours, colors, normals + block layout); voxels = all "
      "levels.\n"
      "VDB: OpenVDB tools::meshToLevelSet<FloatGrid>, voxel = scene cube / {}, half width {:.0f}; voxels = "
      "active.\n"
      "vs VDB: speed ratio at the same thread count (> 1: ESVO faster). Threads: tbb::global_control.\n"
      "peak RSS: getrusage ru_maxrss, {}; the loaded mesh included.\n"
      "1- and 2-thread octrees byte-identical: {}\n",
      resolution, kLevelSetHalfWidth,
      peaksReset ? "the peak reset before each row (/proc/self/clear_refs)"
                 : "a process-wide peak (resetting it was refused), so rows only grow",
      std::adjacent_find(hashes.begin(), hashes.end(), std::not_equal_to<>()) == hashes.end() ? "yes" : "NO");
}

// ----- the store measurements ------------------------------------------------------------------------------

// Warm decoding: readSlice against plain zstd on the same bytes in memory, over the first slices up to
// kWarmSampleBytes.
struct WarmDecoding {
  Paired timing;  // a: readSlice, b: ZSTD_decompress
  std::size_t slices = 0;
  std::uint64_t compressedBytes = 0, rawBytes = 0, sink = 0;
};
WarmDecoding measureWarmDecoding(const StoreReader& reader, const CachedFile& file,
                                 std::uint32_t largestSlice, int runs) {
  const std::filesystem::path& path = reader.path();
  const std::vector<SliceInfo>& slices = reader.slices();
  WarmDecoding r;
  while (r.slices < slices.size() &&
         (r.slices == 0 || r.compressedBytes + slices[r.slices].compressedBytes <= kWarmSampleBytes)) {
    r.compressedBytes += slices[r.slices].compressedBytes;
    r.rawBytes += slices[r.slices].rawBytes;
    ++r.slices;
  }
  std::vector<std::vector<char>> compressed(r.slices);
  for (std::size_t i = 0; i < r.slices; ++i) {
    compressed[i].resize(slices[i].compressedBytes);
    if (::pread(file.fd(), compressed[i].data(), compressed[i].size(), off_t(slices[i].offset)) !=
        ssize_t(compressed[i].size()))
      throw std::runtime_error(path.string() + ": cannot read slice " + std::to_string(i));
  }
  spdlog::info("slice decoding, warm: {} of {} slices, {} runs ...", r.slices, slices.size(), runs);
  const auto readPass = [&] {
    for (std::uint32_t id = 0; id < r.slices; ++id) r.sink += reader.readSlice(id).size();
  };
  std::vector<char> out(largestSlice);
  const auto zstdPass = [&] {
    for (std::size_t i = 0; i < r.slices; ++i) {
      const std::size_t n =
          ZSTD_decompress(out.data(), slices[i].rawBytes, compressed[i].data(), compressed[i].size());
      if (ZSTD_isError(n))
        throw std::runtime_error(path.string() + ": slice " + std::to_string(i) + " does not decompress");
      r.sink += n;
    }
  };
  r.timing = timePaired(runs, readPass, zstdPass);
  return r;
}

// Cold reads in a fixed random slice order, readSlice and bare pread, each with one reader and with
// `readThreads` readers, against dd's sequential read; the page cache is dropped before every run.
struct ColdReads {
  std::vector<int> readerCounts;
  std::vector<std::vector<double>> readSlice, pread;  // seconds per run, per reader count
  std::optional<Summary> dd;                          // none when dd failed
  std::uint64_t ddBytes = 0;
  double maxResident = 0.0;  // largest share of the file still cached at a run's start
  std::uint64_t sink = 0;
};
ColdReads measureColdReads(const StoreReader& reader, const CachedFile& file, int runs, int readThreads) {
  const std::vector<SliceInfo>& slices = reader.slices();
  std::vector<std::uint32_t> order(slices.size());
  std::iota(order.begin(), order.end(), 0u);
  std::shuffle(order.begin(), order.end(), std::mt19937_64(kShuffleSeed));
  ColdReads r;
  r.readerCounts = readThreads > 1 ? std::vector<int>{1, readThreads} : std::vector<int>{1};
  r.readSlice.resize(r.readerCounts.size());
  r.pread.resize(r.readerCounts.size());
  std::vector<double> ddSeconds, residents;
  std::uint32_t largestCompressed = 0;
  for (const SliceInfo& s : slices) largestCompressed = std::max(largestCompressed, s.compressedBytes);
  bool ddRan = true;
  std::atomic<std::size_t> readSink{0};
  spdlog::info("cold reads: random slice order vs dd, {} runs ...", runs);
  for (int i = 0; i < runs; ++i) {
    for (std::size_t c = 0; c < r.readerCounts.size(); ++c) {
      file.drop();
      residents.push_back(file.resident());
      r.readSlice[c].push_back(timeConcurrentReads(
          order, r.readerCounts[c], [&](std::uint32_t id) { readSink += reader.readSlice(id).size(); }));
      file.drop();
      residents.push_back(file.resident());
      r.pread[c].push_back(timeConcurrentReads(order, r.readerCounts[c], [&](std::uint32_t id) {
        thread_local std::vector<char> buffer;
        buffer.resize(largestCompressed);
        readSink += std::size_t(
            ::pread(file.fd(), buffer.data(), slices[id].compressedBytes, off_t(slices[id].offset)));
      }));
    }
    file.drop();
    residents.push_back(file.resident());
    if (const std::optional<DdResult> dd = runDd(reader.path())) {
      ddSeconds.push_back(dd->seconds);
      r.ddBytes = dd->bytes;
    } else {
      ddRan = false;
    }
  }
  r.sink = readSink;
  if (ddRan) r.dd = summarize(ddSeconds);
  r.maxResident = *std::max_element(residents.begin(), residents.end());
  return r;
}

void printDecoding(const WarmDecoding& warm, std::size_t slices) {
  const double raw = double(warm.rawBytes);
  const Summary &ours = warm.timing.a, &plain = warm.timing.b;
  if (warm.slices < slices)
    fmt::print("warm rows: the first {} of {} slices ({} MiB compressed, held in memory for zstd)\n",
               warm.slices, slices, mib(double(warm.compressedBytes)));
  Table decode({"warm page cache", "decoded MB/s", "min/max", "time", "vs zstd", "goal"});
  decode.addRow({"StoreReader::readSlice (read + XXH3 + zstd)", mbs(raw, ours.median),
                 fmt::format("{} / {}", mbs(raw, ours.max), mbs(raw, ours.min)), formatSeconds(ours.median),
                 fmt::format("{:.2f}x", warm.timing.ratio), fmt::format(">= {:.1f}x", kDecodeGoal)});
  decode.addRow({"ZSTD_decompress, same bytes in memory", mbs(raw, plain.median),
                 fmt::format("{} / {}", mbs(raw, plain.max), mbs(raw, plain.min)),
                 formatSeconds(plain.median), "1.00x", ""});
  decode.print();
}

void printColdReads(const ColdReads& cold, double diskBytes, std::size_t slices) {
  Table coldTable({"cold file (page cache dropped)", "file MB/s", "min/max", "time", "vs dd", "goal"});
  const auto coldRow = [&](const std::string& name, const Summary& s, double bytes, bool goal) {
    coldTable.addRow(
        {name, mbs(bytes, s.median), fmt::format("{} / {}", mbs(bytes, s.max), mbs(bytes, s.min)),
         formatSeconds(s.median),
         cold.dd ? fmt::format("{:.2f}x", megabytesPerSecond(bytes, s.median) /
                                              megabytesPerSecond(double(cold.ddBytes), cold.dd->median))
                 : std::string("dd failed"),
         goal ? fmt::format(">= {:.1f}x", kColdReadGoal) : std::string()});
  };
  for (std::size_t c = 0; c < cold.readerCounts.size(); ++c) {
    const std::string readers =
        cold.readerCounts[c] == 1 ? "1 reader" : fmt::format("{} readers", cold.readerCounts[c]);
    coldRow(fmt::format("readSlice, random slice order, {}", readers), summarize(cold.readSlice[c]),
            diskBytes, c + 1 == cold.readerCounts.size());
    coldRow(fmt::format("pread only, random slice order, {}", readers), summarize(cold.pread[c]), diskBytes,
            false);
  }
  if (cold.dd)
    coldRow("dd if=FILE of=/dev/null bs=1M", *cold.dd, double(cold.ddBytes), false);
  else
    coldTable.addRow({"dd if=FILE of=/dev/null bs=1M", "dd failed"});
  coldTable.print();
  fmt::print(
      "decoded MB/s: decoded slice bytes per second (10^6); warm rows alternate, and vs zstd is the median "
      "of\n"
      "the per-sample speed ratios. file MB/s: bytes read from the file per second\n"
      "(slices' compressed bytes; dd: the whole file). Cold: posix_fadvise(POSIX_FADV_DONTNEED) on the file\n"
      "before every run; at most {:.1f}% of its pages were still cached at a run's start (mincore). A "
      "virtual\n"
      "disk may still be cached by its host. Random order: a fixed shuffle of all {} slices.\n",
      100.0 * cold.maxResident, slices);
}

void printSliceSizes(const std::vector<SliceInfo>& slices, const StoreHeader& h) {
  printTitle("Slice sizes");
  // Slices whose cube is one voxel of the level above cannot split; the goals are about the others.
  std::vector<double> splittable;
  std::size_t unsplittable = 0, overLimit = 0;
  for (const SliceInfo& s : slices) {
    const double size = double(s.rawBytes) / double(h.sliceBytes);
    if (!s.canSplit()) {
      ++unsplittable;
      continue;
    }
    splittable.push_back(size);
    overLimit += size > kLargestSliceGoal;
  }
  std::sort(splittable.begin(), splittable.end());
  const auto quantile = [&](double q) {
    return splittable.empty() ? 0.0 : splittable[std::size_t(q * double(splittable.size() - 1) + 0.5)];
  };
  Table sizes({"decoded slice size / target", "p10", "median", "p90", "largest", "above 1.5x", "goal"});
  sizes.addRow({fmt::format("{} slices that can split", splittable.size()),
                fmt::format("{:.2f}", quantile(0.1)), fmt::format("{:.2f}", quantile(0.5)),
                fmt::format("{:.2f}", quantile(0.9)), fmt::format("{:.2f}", quantile(1.0)),
                std::to_string(overLimit),
                fmt::format("median >= {:.1f}, none above {:.1f}", kMedianSliceGoal, kLargestSliceGoal)});
  sizes.print();
  fmt::print("target: {} B decoded; {} more slices hold the children of a single voxel (cannot split)\n",
             h.sliceBytes, unsplittable);
}

// Bytes per leaf voxel, per part: raw bytes exactly, disk bytes by each slice's compression ratio.
void printBytesPerLeaf(const StoreReader& reader, const LevelSummary& total, std::uint64_t leaves) {
  const StoreHeader& h = reader.header();
  double diskHierarchy = 0, diskContours = 0, diskColors = 0, diskNormals = 0;
  for (const SliceInfo& s : reader.slices()) {
    const LevelSummary l = summarizeSlice(s, h);
    const double ratio = l.rawBytes ? double(l.diskBytes) / double(l.rawBytes) : 0.0;
    diskHierarchy += ratio * double(l.hierarchyBytes), diskContours += ratio * double(l.contourBytes);
    diskColors += ratio * double(l.colorBytes), diskNormals += ratio * double(l.normalBytes);
  }
  printTitle("Bytes per leaf voxel");
  fmt::print("{} leaf voxels (voxels without children), {} voxels in all\n", formatCount(leaves),
             formatCount(total.voxels + 1));
  Table bytes({"part", "raw B/leaf", "disk B/leaf", "disk share"});
  const double fileBytes = double(h.fileBytes), raw = double(total.rawBytes), disk = double(total.diskBytes);
  const auto bytesRow = [&](const std::string& name, double rawPart, double diskPart) {
    bytes.addRow({name, fmt::format("{:.3f}", rawPart / double(leaves)),
                  fmt::format("{:.3f}", diskPart / double(leaves)),
                  fmt::format("{:.1f}%", 100.0 * diskPart / fileBytes)});
  };
  bytesRow("hierarchy (split bits, valid masks, slice heads)", double(total.hierarchyBytes), diskHierarchy);
  bytesRow("contours", double(total.contourBytes), diskContours);
  if (h.hasColors) bytesRow("color attachment", double(total.colorBytes), diskColors);
  if (h.hasNormals) bytesRow("normal attachment", double(total.normalBytes), diskNormals);
  bytesRow("all slices", raw, disk);
  bytesRow("whole file (+ header, directory)", raw + (fileBytes - disk), fileBytes);
  bytes.print();
  fmt::print(
      "raw: decoded slice sections (as svo inspect counts them); disk: compressed, each slice's bytes "
      "shared\n"
      "among its parts in proportion to their raw sizes (zstd compresses a slice as a whole). Goal: <= 3 B "
      "per\n"
      "leaf voxel on disk with contours and attributes.\n");
}

void benchStore(const std::filesystem::path& path, int runs, int readThreads) {
  const StoreReader reader(path);
  const StoreHeader& h = reader.header();
  const std::vector<SliceInfo>& slices = reader.slices();
  if (slices.empty()) throw std::runtime_error(path.string() + ": the store has no slices to measure");
  const CachedFile file(path);
  LevelSummary total;
  for (const SliceInfo& s : slices) add(total, summarizeSlice(s, h));
  spdlog::info("{}: counting leaf voxels (svo verify's walk, one slice chain in memory) ...", path.string());
  std::uint64_t leaves = 0;
  reader.verify(nullptr, &leaves);

  const WarmDecoding warm = measureWarmDecoding(reader, file, total.largestSlice, runs);
  const ColdReads cold = measureColdReads(reader, file, runs, readThreads);
  const LoadCosts load = measureLoadCosts(reader, runs);
  printTitle("Slice store: read, verify, decode");
  fmt::print(
      "{}: {} MiB, {} slices ({} decoded MiB, slice size {} B), {} levels, attachments:{}{}; median of {} "
      "runs\n",
      path.string(), mib(double(h.fileBytes)), slices.size(), mib(double(total.rawBytes)), h.sliceBytes,
      h.parameters.levels, h.hasColors ? " color" : "",
      h.hasNormals ? " normal" : (h.hasColors ? "" : " none"), runs);
  printDecoding(warm, slices.size());
  printColdReads(cold, double(total.diskBytes), slices.size());
  printSliceSizes(slices, h);
  printBytesPerLeaf(reader, total, leaves);
  printLoadCosts(load);
  if (warm.sink + cold.sink == 0) fmt::print("(nothing read)\n");
}

void runStoreBench(const StoreArgs& args) {
  requireRuns(args.runs);
  if (!std::filesystem::exists(args.input)) throw std::runtime_error(args.input + ": no such file");
  if (isStore(args.input)) {
    benchStore(args.input, args.runs, args.readThreads);
    return;
  }
  // A mesh: build it, then measure the store that was written. A store path not given is a temporary file
  // next to the system's others, removed at the end.
  std::optional<ScratchPath> scratch;
  std::filesystem::path storePath = args.store;
  if (storePath.empty())
    storePath = scratch.emplace("svo-bench-store.svo").path();
  else
    checkWritableOutput(storePath);
  benchBuild(args, storePath);
  benchStore(storePath, args.runs, args.readThreads);
}

}  // namespace

void addStoreBench(CLI::App& bench) {
  auto args = std::make_shared<StoreArgs>();
  CLI::App* cmd = bench.add_subcommand(
      "store",
      "slice read/verify/decode vs zstd, cold random reads vs dd, bytes per voxel; for a mesh also "
      "the build on 1 and 2 threads vs OpenVDB");
  cmd->add_option("input", args->input, "a .svo store, or a mesh to build one from")->required();
  cmd->add_option("--levels", args->levels, "octree depth when building a mesh (OpenVDB: 2^levels voxels)")
      ->check(CLI::Range(1, kMaxLevels))
      ->capture_default_str();
  cmd->add_option("--runs", args->runs, "timed runs per measurement; the median is reported")
      ->capture_default_str();
  cmd->add_option("--read-threads", args->readThreads,
                  "cold random reads also with this many concurrent readers (the pager's workers)")
      ->check(CLI::Range(1, 64))
      ->capture_default_str();
  cmd->add_option("--store", args->store,
                  "when building a mesh: keep the store at this path (default: a "
                  "temporary file, removed)");
  cmd->callback([args] { runStoreBench(*args); });
}

}  // namespace svo::tools::bench
