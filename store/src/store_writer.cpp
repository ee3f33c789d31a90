#include "svo/store/store_writer.hpp"

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <system_error>
#include <utility>

#include <tbb/enumerable_thread_specific.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_pipeline.h>
#include <tbb/task_arena.h>
#include <unistd.h>
#include <xxhash.h>
#include <zstd.h>

#include "file_layout.hpp"
#include "svo/store/codec.hpp"

namespace svo {
namespace {

// zstd for slices: its optimal parser (btopt), matches of 6 bytes or more. A slice's byte planes of
// prediction residuals are mostly literals, and the parser leaves fewer stray short matches in them than
// level 3's greedy search. Sweep of levels 3-19, strategies and minimum matches on the 2M terrain at 12
// levels, a 200k terrain and the bunny: 8-12% smaller than level 3, within 0.5% of level 19's best, the
// fastest of those; reads are no slower (svo bench stream, read + zstd).
constexpr int kZstdLevel = 9;
constexpr ZSTD_strategy kZstdStrategy = ZSTD_btopt;
constexpr int kZstdMinMatch = 6;
// Slices queued before they are compressed together: enough to keep every core busy, ~1 MiB each.
std::size_t compressBatch() {
  return 2 * std::size_t(std::max(1, tbb::this_task_arena::max_concurrency()));
}

struct FreeCompressor {
  void operator()(ZSTD_CCtx* c) const { ZSTD_freeCCtx(c); }
};
using Compressor = std::unique_ptr<ZSTD_CCtx, FreeCompressor>;

Compressor makeCompressor() {
  Compressor c(ZSTD_createCCtx());
  if (!c) throw std::bad_alloc();
  ZSTD_CCtx_setParameter(c.get(), ZSTD_c_compressionLevel, kZstdLevel);
  ZSTD_CCtx_setParameter(c.get(), ZSTD_c_strategy, kZstdStrategy);
  ZSTD_CCtx_setParameter(c.get(), ZSTD_c_minMatch, kZstdMinMatch);
  return c;
}

[[noreturn]] void failWrite(const std::filesystem::path& path) {
  file::fail(path.string(), std::string("cannot write (") + std::strerror(errno) + ")");
}

// Where the planner sends the slices of a tree without cells: written at once, in plan order.
class FileSink : public SliceSink {
 public:
  using Write = std::function<std::uint32_t(const std::vector<std::byte>&, const SliceInfo&)>;
  explicit FileSink(Write write) : write_(std::move(write)) {}
  std::uint32_t emit(const std::vector<std::byte>& raw, const SliceInfo& info) override {
    return write_(raw, info);
  }
  std::uint32_t reserve(const SliceInfo&, const SliceHead&, std::size_t, std::size_t) override {
    throw std::logic_error("writeStore: a tree without cells reserved a slice");
  }
  void delegate(std::size_t, int, std::uint32_t) override {
    throw std::logic_error("writeStore: a tree without cells handed on a cell");
  }

 private:
  Write write_;
};

// The out-of-core top's sink: its own levels are written at once; slices of cell levels that span several
// cells are reserved (an id in plan order, so parents still come first) and written once their last cell
// has given its part; a run within one cell is left to that cell.
class ForestSink : public FileSink {
 public:
  struct Reserved {
    SliceHead head;
    std::size_t lastCell;
    SliceSections parts;
  };
  ForestSink(Write write, std::vector<SliceInfo>& slices, std::size_t cells)
      : FileSink(std::move(write)),
        cellParts(cells),
        cellStart(cells, {0, SliceInfo::kNoSlice}),
        slices_(slices) {}

  std::uint32_t reserve(const SliceInfo& info, const SliceHead& head, std::size_t a, std::size_t b) override {
    const auto id = std::uint32_t(slices_.size());
    slices_.push_back(info);
    reserved.emplace(id, Reserved{head, b - 1, SliceSections(head.attachments & 1u, head.attachments & 2u)});
    for (std::size_t cell = a; cell < b; ++cell) cellParts[cell].push_back({info.voxelLevel, id});
    return id;
  }
  void delegate(std::size_t cell, int level, std::uint32_t parentSlice) override {
    cellStart[cell] = {level, parentSlice};
  }

  std::map<std::uint32_t, Reserved> reserved;
  std::vector<std::vector<std::pair<int, std::uint32_t>>> cellParts;  // per cell: (level, reserved slice)
  std::vector<std::pair<int, std::uint32_t>> cellStart;  // per cell: (first level, parent slice) of its own

 private:
  std::vector<SliceInfo>& slices_;
};

SlicePlanner plannerOf(const VoxelTree& tree, const StoreWriteOptions& options, const SubtreePlacement& at) {
  return SlicePlanner(tree, options.sliceBytes, options.inheritance, at);
}

void requireVoxelsBelowRoot(const VoxelTree& tree) {
  if (tree.voxels.empty() || tree.voxels[0].childMask == 0)
    throw std::invalid_argument("writeStore: the tree has no voxels below the root");
}

}  // namespace

StoreFileWriter::StoreFileWriter(const std::filesystem::path& path, const StoreWriteOptions& options)
    : path_(path),
      temp_(path.string() + ".tmp." + std::to_string(::getpid())),
      options_(options),
      compression_(std::make_unique<tbb::task_group>()) {
  if (options.sliceBytes < file::kMinSliceBytes)
    throw std::invalid_argument("writeStore: slice size must be at least " +
                                std::to_string(file::kMinSliceBytes) + " bytes (got " +
                                std::to_string(options.sliceBytes) + ")");
  // Temporary name in the same folder, flushed, then renamed: the target is never half-written.
  file_ = std::fopen(temp_.c_str(), "wb");
  if (!file_) failWrite(path_);
  const file::Header placeholder{};  // until the directory's place is known
  try {
    put(&placeholder, sizeof placeholder);
  } catch (...) {
    std::fclose(file_);  // no destructor runs for a constructor that throws
    std::error_code ignored;
    std::filesystem::remove(temp_, ignored);
    throw;
  }
  offset_ = sizeof placeholder;
}

StoreFileWriter::~StoreFileWriter() {
  try {
    compression_->wait();  // its tasks use this writer
  } catch (...) {
  }
  if (!file_) return;
  std::fclose(file_);
  std::error_code ignored;
  std::filesystem::remove(temp_, ignored);
}

void StoreFileWriter::put(const void* data, std::size_t bytes) {
  if (std::fwrite(data, 1, bytes, file_) != bytes) failWrite(path_);
}

std::uint32_t StoreFileWriter::writeSlice(const std::vector<std::byte>& raw, SliceInfo info,
                                          std::uint32_t reserved) {
  info.rawBytes = std::uint32_t(raw.size());
  info.compressedBytes = 0;  // until its batch is written (startCompressing)
  std::uint32_t id = reserved;
  if (reserved != SliceInfo::kNoSlice) {
    slices_[reserved] = info;
  } else {
    id = std::uint32_t(slices_.size());
    slices_.push_back(info);
  }
  pending_.push_back({id, raw, {}});
  if (pending_.size() >= compressBatch()) startCompressing();
  return id;
}

void StoreFileWriter::startCompressing() {
  compression_->wait();                         // rethrows a failed compression
  for (const PendingSlice& p : compressing_) {  // in the order they came: the same file on any core count
    SliceInfo& info = slices_[p.id];
    info.offset = offset_;
    info.compressedBytes = std::uint32_t(p.compressed.size());
    info.checksum = XXH3_64bits(p.compressed.data(), p.compressed.size());
    put(p.compressed.data(), p.compressed.size());
    offset_ += p.compressed.size();
  }
  compressing_.swap(pending_);
  pending_.clear();
  if (compressing_.empty()) return;
  compression_->run([this] {
    static tbb::enumerable_thread_specific<Compressor> compressors(makeCompressor);
    tbb::parallel_for(std::size_t(0), compressing_.size(), [&](std::size_t i) {
      PendingSlice& p = compressing_[i];
      p.compressed.resize(ZSTD_compressBound(p.raw.size()));
      const std::size_t packed = ZSTD_compress2(compressors.local().get(), p.compressed.data(),
                                                p.compressed.size(), p.raw.data(), p.raw.size());
      if (ZSTD_isError(packed))
        file::fail(path_.string(), std::string("compression failed: ") + ZSTD_getErrorName(packed));
      p.compressed.resize(packed);
    });
  });
}

void StoreFileWriter::flush() {
  startCompressing();
  startCompressing();  // writes what the first one started
}

std::vector<std::uint32_t> StoreFileWriter::append(const VoxelTree& tree, const SubtreePlacement& at,
                                                   EffectiveAttributes* effective) {
  if (!file_) throw std::logic_error("StoreFileWriter: append after finish");
  if (at.parentSlice != SliceInfo::kNoSlice && at.parentSlice >= slices_.size())
    throw std::invalid_argument("writeStore: a subtree's parent slice is not written yet");
  requireVoxelsBelowRoot(tree);
  const SlicePlanner planner = plannerOf(tree, options_, at);
  std::vector<std::uint32_t> ids;
  std::uint64_t voxelsWritten = 1;  // the root is the parent slice's (or the header's)
  FileSink sink([&](const std::vector<std::byte>& raw, const SliceInfo& info) {
    ids.push_back(writeSlice(raw, info));
    voxelsWritten += info.voxelCount;
    if (options_.progress) options_.progress(double(voxelsWritten) / double(planner.voxelCount()));
    return ids.back();
  });
  planner.run(sink);
  flush();
  if (effective) *effective = planner.effective();
  return ids;
}

void StoreFileWriter::appendForest(const VoxelTree& top, int cellLevel,
                                   const std::function<VoxelTree(glm::ivec3 cell, bool counting)>& loadCell) {
  if (!file_) throw std::logic_error("StoreFileWriter: append after finish");
  if (!slices_.empty()) throw std::logic_error("StoreFileWriter: a forest must be the store's first subtree");
  requireVoxelsBelowRoot(top);
  const VoxelRecord& root = top.voxels[0];
  SlicePlanner topPlanner =
      plannerOf(top, options_, {0, glm::ivec3(0), root.color, root.normal, SliceInfo::kNoSlice});
  std::vector<std::pair<std::uint32_t, glm::ivec3>> cells;
  if (topPlanner.topLevel() == cellLevel) cells = topPlanner.deepestVoxels();
  const EffectiveAttributes effective = topPlanner.effective();
  const auto placement = [&](std::size_t i) {
    const auto [record, coord] = cells[i];
    return SubtreePlacement{cellLevel, coord, effective.color[record], effective.normal[record],
                            SliceInfo::kNoSlice};
  };
  std::mutex progressMutex;
  std::size_t done = 0;  // cells counted, then cells written
  const auto progress = [&] {
    std::lock_guard lock(progressMutex);
    ++done;
    if (options_.progress)
      options_.progress(double(done) / double(std::max<std::size_t>(2 * cells.size(), 1)));
  };
  // 1. Every cell's totals per level, cells in parallel: the plan's sizes for slices spanning cells.
  std::vector<std::vector<LevelTotals>> totals(cells.size());
  tbb::parallel_for(std::size_t(0), cells.size(), [&](std::size_t i) {
    totals[i] = plannerOf(loadCell(cells[i].second, true), options_, placement(i)).totals();
    progress();
  });
  topPlanner.addCells(totals);
  // 2. The plan: the top's slices written, the spanning ones reserved, the rest handed to their cells.
  const auto write = [&](const std::vector<std::byte>& raw, const SliceInfo& info) {
    return writeSlice(raw, info);
  };
  ForestSink sink(write, slices_, cells.size());
  topPlanner.run(sink);
  // 3. Each cell, loaded and planned in parallel, then in Morton order: its parts of the spanning slices (a
  // slice is written when its last cell is done), then its own slices.
  struct PlannedCell {
    std::size_t index = 0;
    VoxelTree tree;
    std::optional<SlicePlanner> plan;  // refers to `tree`
  };
  using Planned = std::shared_ptr<PlannedCell>;  // pipeline items are copied
  FileSink own(write);
  std::size_t next = 0;
  const std::size_t inFlight =
      std::min<std::size_t>(tbb::this_task_arena::max_concurrency(),
                            tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism));
  tbb::parallel_pipeline(
      std::max<std::size_t>(inFlight, 1),
      tbb::make_filter<void, std::size_t>(tbb::filter_mode::serial_in_order,
                                          [&](tbb::flow_control& control) -> std::size_t {
                                            if (next == cells.size()) control.stop();
                                            return next++;
                                          }) &
          tbb::make_filter<std::size_t, Planned>(tbb::filter_mode::parallel,
                                                 [&](std::size_t i) {
                                                   auto c = std::make_shared<PlannedCell>();
                                                   c->index = i;
                                                   c->tree = loadCell(cells[i].second, false);
                                                   c->plan.emplace(
                                                       plannerOf(c->tree, options_, placement(i)));
                                                   return c;
                                                 }) &
          tbb::make_filter<Planned, void>(tbb::filter_mode::serial_in_order, [&](const Planned& c) {
            const std::size_t i = c->index;
            for (const auto& [level, id] : sink.cellParts[i]) {
              ForestSink::Reserved& r = sink.reserved.at(id);
              r.parts.append(c->plan->sectionsOfLevel(level));
              if (r.lastCell != i) continue;
              writeSlice(encodeSlice(r.head, r.parts), slices_[id], id);
              sink.reserved.erase(id);
            }
            if (const auto [level, parent] = sink.cellStart[i]; parent != SliceInfo::kNoSlice)
              c->plan->runFrom(level, parent, own);
            progress();
          }));
  if (!sink.reserved.empty()) throw std::logic_error("writeStore: a slice spanning cells was not completed");
  flush();
}

void StoreFileWriter::finish(const StoreContents& contents) {
  if (!file_) throw std::logic_error("StoreFileWriter: finish twice");
  if (slices_.empty()) throw std::invalid_argument("writeStore: the store has no slices");
  flush();
  for (const SliceInfo& slice : slices_)
    if (slice.compressedBytes == 0) throw std::logic_error("writeStore: a reserved slice was never written");
  std::vector<file::DirectoryEntry> directory(slices_.size());
  for (std::size_t i = 0; i < slices_.size(); ++i) directory[i] = file::entryOf(slices_[i]);
  const std::size_t directoryBytes = directory.size() * sizeof(file::DirectoryEntry);
  put(directory.data(), directoryBytes);

  file::Header h{};
  std::memcpy(h.magic, kFileMagic, sizeof h.magic);
  h.version = kFileVersion;
  h.headerBytes = sizeof(file::Header);
  for (int i = 0; i < 3; ++i) h.origin[i] = contents.transform.origin[i];
  h.size = contents.transform.size;
  h.levels = contents.parameters.levels;
  h.geometryError = contents.parameters.geometryError;
  h.colorError = contents.parameters.colorError;
  h.normalError = contents.parameters.normalError;
  h.contours = contents.parameters.contours;
  if (contents.hasColors) h.attachmentTypes |= 1u << (std::uint32_t(AttachmentType::Color) - 1);
  if (contents.hasNormals) h.attachmentTypes |= 1u << (std::uint32_t(AttachmentType::Normal) - 1);
  h.rootColor = contents.rootColor;
  h.rootNormal = contents.rootNormal;
  h.sliceBytes = options_.sliceBytes;
  h.sliceCount = std::uint32_t(slices_.size());
  h.directoryOffset = offset_;
  h.directoryBytes = directoryBytes;
  h.directoryChecksum = XXH3_64bits(directory.data(), directoryBytes);
  h.headerChecksum = file::headerChecksum(h);
  if (std::fseek(file_, 0, SEEK_SET) != 0) file::fail(path_.string(), "cannot seek to the header");
  put(&h, sizeof h);
  if (std::fflush(file_) != 0 || ::fsync(::fileno(file_)) != 0) failWrite(path_);
  const int closed = std::fclose(file_);
  file_ = nullptr;
  std::error_code ignored;
  if (closed != 0) {
    std::filesystem::remove(temp_, ignored);
    failWrite(path_);
  }
  std::error_code ec;
  std::filesystem::rename(temp_, path_, ec);
  if (ec) {
    std::filesystem::remove(temp_, ignored);
    file::fail(path_.string(), "cannot rename into place (" + ec.message() + ")");
  }
}

std::vector<SliceInfo> writeStore(const std::filesystem::path& path, const VoxelTree& tree,
                                  const SceneTransform& transform, const BuildParameters& parameters,
                                  const StoreWriteOptions& options) {
  requireVoxelsBelowRoot(tree);
  StoreFileWriter writer(path, options);
  const VoxelRecord& root = tree.voxels[0];
  writer.append(tree, {0, glm::ivec3(0), root.color, root.normal, SliceInfo::kNoSlice});
  std::vector<SliceInfo> slices = writer.slices();
  writer.finish({transform, parameters, tree.hasColors, tree.hasNormals, root.color, root.normal});
  return slices;
}

void writeOctree(const std::filesystem::path& path, const Octree& octree, const StoreWriteOptions& options) {
  writeStore(path, readBlock(octree.block.view()), octree.transform, octree.parameters, options);
}

}  // namespace svo
