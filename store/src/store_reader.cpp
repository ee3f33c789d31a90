#include "svo/store/store_reader.hpp"

#include <algorithm>
#include <cassert>
#include <memory>
#include <new>
#include <string>
#include <utility>

#include <xxhash.h>
#include <zstd.h>

#include "file_layout.hpp"
#include "svo/store/codec.hpp"

namespace svo {

std::span<SliceVoxel> sliceParents(const StoreIndex& index, std::uint32_t slice,
                                   std::span<SliceVoxel> level) {
  // The run's voxels one level above the slice: a contiguous Morton range.
  const SliceInfo& s = index.slices().at(slice);
  glm::ivec3 first, last;
  if (s.wholeCube()) {
    const int shift = s.voxelLevel - 1 - s.cubeLevel;
    first = s.cubeCoord << shift, last = first + ((1 << shift) - 1);
  } else {
    const int shift = s.voxelLevel - 1 - (s.cubeLevel + 1);  // the index checked that the sub-cubes fit
    first = childCoord(s.cubeCoord, s.firstSlot) << shift;
    last = (childCoord(s.cubeCoord, s.lastSlot) << shift) + ((1 << shift) - 1);
  }
  const auto lo =
      std::lower_bound(level.begin(), level.end(), first,
                       [](const SliceVoxel& n, const glm::ivec3& k) { return mortonLess(n.coord, k); });
  const auto hi = std::upper_bound(
      lo, level.end(), last, [](const glm::ivec3& k, const SliceVoxel& n) { return mortonLess(k, n.coord); });
  return {lo, hi};
}

namespace {

// Slice `id`'s parents (sliceParents), each marked in `covered`; one marked before means two slices claim it.
std::span<SliceVoxel> claimParents(const StoreIndex& index, std::uint32_t id, std::vector<SliceVoxel>& level,
                                   std::vector<std::uint8_t>& covered) {
  const std::span<SliceVoxel> parents = sliceParents(index, id, level);
  for (std::size_t p = std::size_t(parents.data() - level.data()), end = p + parents.size(); p < end; ++p) {
    if (covered[p]) throw index.sliceError(id, "overlaps another slice's sub-cubes");
    covered[p] = 1;
  }
  return parents;
}

// The root voxel as the header gives it: the parent of the first slice.
SliceVoxel rootVoxel(const StoreHeader& header) {
  return {.color = header.rootColor, .normal = header.rootNormal};
}

}  // namespace

namespace {

// Reads `out.size()` bytes at `offset` for slices from `slice` on; a failure throws `slice`'s SliceError,
// transient when the source's failure may pass.
void readForSlice(const ByteSource& source, const StoreIndex& index, std::uint32_t slice,
                  std::uint64_t offset, std::span<std::byte> out) {
  std::size_t read = 0;
  try {
    read = source.read(offset, out);
  } catch (const ByteSourceError& e) {
    SliceError error = index.sliceError(slice, e.what());
    error.transient = dynamic_cast<const TransientSourceError*>(&e) != nullptr;
    throw error;
  }
  if (read != out.size()) throw index.sliceError(slice, "truncated");
}

}  // namespace

void fetchSlice(const ByteSource& source, const StoreIndex& index, std::uint32_t slice,
                SliceBytes& compressed) {
  if (slice >= index.slices().size()) throw index.sliceError(slice, "no such slice");
  const SliceInfo& s = index.slices()[slice];
  compressed.resize(s.compressedBytes);
  readForSlice(source, index, slice, s.offset, compressed);
}

void fetchSlices(const ByteSource& source, const StoreIndex& index, std::span<const std::uint32_t> slices,
                 std::vector<SliceBytes>& compressed) {
  const std::vector<SliceInfo>& info = index.slices();
  for (std::size_t i = 0; i < slices.size();) {
    if (slices[i] >= info.size()) throw index.sliceError(slices[i], "no such slice");
    // The run from slice i on that lies back to back in the file.
    const std::uint64_t start = info[slices[i]].offset;
    std::uint64_t end = start + info[slices[i]].compressedBytes;
    std::size_t j = i + 1;
    for (; j < slices.size() && slices[j] < info.size() && info[slices[j]].offset == end &&
           end + info[slices[j]].compressedBytes - start <= kMaxSlicesReadBytes;
         ++j)
      end += info[slices[j]].compressedBytes;
    if (j == i + 1) {
      SliceBytes bytes;
      fetchSlice(source, index, slices[i], bytes);
      compressed.push_back(std::move(bytes));
    } else {
      SliceBytes run(end - start);
      readForSlice(source, index, slices[i], start, run);
      for (std::size_t k = i; k < j; ++k) {
        const std::byte* from = run.data() + (info[slices[k]].offset - start);
        compressed.emplace_back(from, from + info[slices[k]].compressedBytes);
      }
    }
    i = j;
  }
}

void checkSlice(const StoreIndex& index, std::uint32_t slice, std::span<const std::byte> compressed) {
  if (slice >= index.slices().size()) throw index.sliceError(slice, "no such slice");
  const SliceInfo& s = index.slices()[slice];
  if (compressed.size() != s.compressedBytes)
    throw index.sliceError(slice, "compressed size does not match the directory");
  if (file::kCheckChecksums && XXH3_64bits(compressed.data(), compressed.size()) != s.checksum)
    throw index.sliceError(slice, "checksum mismatch");
}

SliceBytes unpackSlice(const StoreIndex& index, std::uint32_t slice, std::span<const std::byte> compressed) {
  checkSlice(index, slice, compressed);
  const SliceInfo& s = index.slices()[slice];
  if (ZSTD_getFrameContentSize(compressed.data(), compressed.size()) != s.rawBytes)
    throw index.sliceError(slice, "size does not match its compressed frame");
  SliceBytes raw(s.rawBytes);
  // One decompression context per thread, reused: ZSTD_decompress would set one up for every slice.
  thread_local const std::unique_ptr<ZSTD_DCtx, std::size_t (*)(ZSTD_DCtx*)> context(ZSTD_createDCtx(),
                                                                                     ZSTD_freeDCtx);
  if (!context) throw std::bad_alloc();
  const std::size_t got =
      ZSTD_decompressDCtx(context.get(), raw.data(), raw.size(), compressed.data(), compressed.size());
  if (ZSTD_isError(got) || got != s.rawBytes) throw index.sliceError(slice, "does not decompress");
  return raw;
}

void decodeSlice(const StoreIndex& index, std::uint32_t slice, std::span<const std::byte> raw,
                 std::span<SliceVoxel> parents, std::vector<SliceVoxel>& children,
                 const std::function<void()>& pause) {
  try {
    decodeSlice(raw, index.slices().at(slice), index.header(), parents, children, pause);
  } catch (const SliceDecodeError& e) {
    throw index.sliceError(slice, e.what());
  }
}

void decodeSlice(const StoreIndex& index, std::uint32_t slice, std::span<const std::byte> raw,
                 LevelOrderTree& tree, std::size_t parentsBegin, std::size_t parentsEnd,
                 const std::function<void()>& pause) {
  // decodeSlice appends no more than the directory's count: with room for it, the parents stay where they
  // are.
  tree.reserveMore(index.slices().at(slice).voxelCount);
  assert(parentsBegin <= parentsEnd && parentsEnd <= tree.voxels.size());
  const std::span<SliceVoxel> parents(tree.voxels.data() + parentsBegin, parentsEnd - parentsBegin);
  decodeSlice(index, slice, raw, parents, tree.voxels, pause);
}

StoreReader::StoreReader(const std::filesystem::path& path)
    : StoreReader(std::make_shared<const LocalFileSource>(path)) {}

StoreReader::StoreReader(std::shared_ptr<const ByteSource> source)
    : source_(std::move(source)),
      index_(std::make_shared<const StoreIndex>(readStoreIndex(*source_))),
      path_(source_->name()) {}

SliceBytes StoreReader::readSlice(std::uint32_t slice) const {
  // One compressed buffer per thread, reused, without a zero fill per slice (as the decoded bytes).
  thread_local SliceBytes compressed;
  fetchSlice(*source_, *index_, slice, compressed);
  return unpackSlice(*index_, slice, compressed);
}

void StoreReader::walk(const SliceVisit& enter, const SliceVisit& leave) const {
  const StoreIndex& index = *index_;
  const std::vector<SliceInfo>& slices = index.slices();
  const std::span<const std::uint32_t> roots = index.rootSlices();
  if (roots.size() != 1) index.fail(std::to_string(roots.size()) + " slices start the hierarchy (one must)");
  std::size_t visited = 0;
  // Depth first: a slice's voxels stay decoded while the slices below it are walked.
  const auto visit = [&](auto&& self, std::uint32_t id, std::span<SliceVoxel> parents) -> void {
    const SliceInfo& s = slices[id];
    std::vector<SliceVoxel> decoded;
    decodeSlice(id, readSlice(id), parents, decoded);
    ++visited;
    if (enter) enter(id, parents, decoded);
    std::vector<std::uint8_t> covered(decoded.size(), 0);
    for (const std::uint32_t child : index.childSlices(id)) {
      const SliceInfo& c = slices[child];
      if (c.voxelLevel != s.voxelLevel + 1 || !sliceWithin(c, s))
        throw index.sliceError(child, "its sub-cubes do not lie one level below its parent slice's");
      self(self, child, claimParents(index, child, decoded, covered));
    }
    if (leave) leave(id, parents, decoded);
  };
  SliceVoxel root = rootVoxel(index.header());
  visit(visit, roots[0], std::span<SliceVoxel>(&root, 1));
  if (visited != slices.size())
    index.fail(std::to_string(slices.size() - visited) + " slices are not reachable from the first");
}

std::uint64_t StoreReader::verify(const std::function<void(double)>& progress, std::uint64_t* leaves) const {
  std::uint64_t voxels = 1, leafVoxels = 0, visited = 0;
  const double total = double(slices().size());
  walk(
      [&](std::uint32_t, std::span<const SliceVoxel>, std::span<const SliceVoxel> decoded) {
        voxels += decoded.size();
        if (progress) progress(double(++visited) / total);
      },
      [&](std::uint32_t, std::span<const SliceVoxel>, std::span<const SliceVoxel> decoded) {
        // Every slice below has set its parents' child masks by now.
        leafVoxels += std::uint64_t(std::count_if(decoded.begin(), decoded.end(),
                                                  [](const SliceVoxel& v) { return v.childMask == 0; }));
      });
  if (leaves) *leaves = leafVoxels;
  return voxels;
}

VoxelTree StoreReader::loadTree() const {
  const StoreIndex& index = *index_;
  const int levelCount = index.header().parameters.levels;
  VoxelLevels levels(1);
  levels[0].push_back(rootVoxel(index.header()));
  std::vector<std::uint32_t> childSlice;  // per voxel, level by level as the tree's records
  for (int level = 1; level <= levelCount && !index.slicesOfLevel(level).empty(); ++level) {
    std::vector<SliceVoxel>& parents = levels[std::size_t(level - 1)];
    std::vector<std::uint8_t> covered(parents.size(), 0);  // a slice has given this voxel's split bit
    // Slices of one level cover disjoint Morton ranges of their parents and decode their children in their
    // parents' order: decoded in the order of their parent ranges, they append the level in Morton order, in
    // which every parent's children are contiguous and follow their parents' order (no sort of the voxels).
    std::vector<std::pair<std::span<SliceVoxel>, std::uint32_t>> claims;
    for (const std::uint32_t id : index.slicesOfLevel(level))
      claims.push_back({claimParents(index, id, parents, covered), id});
    std::stable_sort(claims.begin(), claims.end(),
                     [](const auto& a, const auto& b) { return a.first.data() < b.first.data(); });
    const std::size_t levelStart = childSlice.size();
    childSlice.resize(levelStart + parents.size(), SliceInfo::kNoSlice);
    for (const auto& [span, id] : claims)
      std::fill_n(childSlice.begin() + std::ptrdiff_t(levelStart + std::size_t(span.data() - parents.data())),
                  span.size(), id);
    std::vector<SliceVoxel> voxels;
    for (const auto& [span, id] : claims) decodeSlice(id, readSlice(id), span, voxels);
    assert(std::is_sorted(voxels.begin(), voxels.end(), [](const SliceVoxel& a, const SliceVoxel& b) {
      return mortonLess(a.coord, b.coord);
    }));
    levels.push_back(std::move(voxels));
  }
  for (std::size_t l = levels.size(); l <= std::size_t(levelCount); ++l)
    if (!index.slicesOfLevel(int(l)).empty())
      index.fail("slices of level " + std::to_string(l) + " have no parents");
  if (levels.size() < 2) index.fail("the store holds no voxels");
  VoxelTree tree = treeOfLevels(levels, index.header().hasColors, index.header().hasNormals);
  childSlice.resize(tree.voxels.size(), SliceInfo::kNoSlice);  // the deepest level has no children
  tree.childSlice = std::move(childSlice);
  return tree;
}

Octree readOctree(const std::filesystem::path& path, AttributeOptions attributes) {
  return readOctree(StoreReader(path), attributes);
}

Octree readOctree(const StoreReader& reader, AttributeOptions attributes) {
  Octree octree;
  octree.transform = reader.header().transform;
  octree.parameters = reader.header().parameters;
  try {
    LayoutOptions layout;
    attributes.applyTo(layout);
    layout.inheritEqualOnly = true;  // the store's values: it already decided what inherits, as the pager
    octree.block = layoutBlock(reader.loadTree(), layout);
  } catch (const std::invalid_argument& e) {
    file::fail(reader.index().name(), e.what());
  }
  return octree;
}

}  // namespace svo
