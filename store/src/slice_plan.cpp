#include "svo/store/slice_plan.hpp"

#include <array>
#include <bit>
#include <cassert>
#include <cmath>
#include <stdexcept>
#include <string>

#include "svo/store/format.hpp"

namespace svo {

SlicePlanner::SlicePlanner(const VoxelTree& tree, std::uint32_t sliceBytes, const LayoutOptions& inheritance,
                           const SubtreePlacement& at)
    : tree_(tree), sliceBytes_(sliceBytes), at_(at) {
  if (tree.voxels.empty()) throw std::invalid_argument("writeStore: the tree has no root");
  if (at.rootLevel < 0 || at.rootLevel >= kMaxLevels)
    throw std::invalid_argument("writeStore: a subtree's root level must be in [0, " +
                                std::to_string(kMaxLevels) + ")");
  resolveAttributes(inheritance);
  countPrefixes();
}

// Walks the tree level by level: each level's voxels in Morton order, and each voxel's effective attributes
// and whether its slice stores them.
void SlicePlanner::resolveAttributes(const LayoutOptions& options) {
  const InheritanceRule inherits(options);
  const std::size_t n = tree_.voxels.size();
  effectiveColor_.assign(n, 0), effectiveNormal_.assign(n, 0);
  storesColor_.assign(n, 0), storesNormal_.assign(n, 0);
  effectiveColor_[0] = at_.rootColor, effectiveNormal_[0] = at_.rootNormal;
  levels_.push_back({{0u, at_.rootCoord}});
  while (true) {
    std::vector<Voxel> next;
    for (const Voxel& parent : levels_.back()) {
      const VoxelRecord& r = tree_.voxels[parent.record];
      const InheritanceRule::ParentNormal parentNormal =
          tree_.hasNormals && r.childMask ? inherits.parentNormal(effectiveNormal_[parent.record])
                                          : InheritanceRule::ParentNormal{};
      for (std::uint32_t c = r.firstChild, slot = 0; slot < 8; ++slot) {
        if (!(r.childMask >> slot & 1u)) continue;
        if (c >= n) throw std::invalid_argument("writeStore: a child index is out of range");
        const VoxelRecord& child = tree_.voxels[c];
        effectiveColor_[c] = effectiveColor_[parent.record];
        effectiveNormal_[c] = effectiveNormal_[parent.record];
        if (tree_.hasColors && !inherits.color(child.color, effectiveColor_[parent.record]))
          storesColor_[c] = 1, effectiveColor_[c] = child.color;
        if (tree_.hasNormals && !inherits.normal(child.normal, parentNormal)) {
          if (latticeNormalBits(octNormalCodeOf(child.normal)) != child.normal)
            throw std::invalid_argument(
                "writeStore: a normal is not on the store's 16-bit lattice (round it with latticeNormal)");
          storesNormal_[c] = 1, effectiveNormal_[c] = child.normal;
        }
        next.push_back({c, childCoord(parent.coord, int(slot))});
        ++c;
      }
    }
    if (next.empty()) break;
    if (std::size_t(at_.rootLevel) + levels_.size() > std::size_t(kMaxLevels))
      throw std::invalid_argument("writeStore: the tree is deeper than " + std::to_string(kMaxLevels) +
                                  " levels");
    levels_.push_back(std::move(next));
  }
}

// Prefix counts per level: children before each voxel, and the voxels with each kind of payload.
void SlicePlanner::countPrefixes() {
  prefix_.resize(levels_.size());
  for (std::size_t l = 0; l < levels_.size(); ++l) {
    Prefix& p = prefix_[l];
    const std::size_t count = levels_[l].size();
    p.children.assign(count + 1, 0), p.splits.assign(count + 1, 0), p.contours.assign(count + 1, 0);
    p.colors.assign(count + 1, 0), p.normals.assign(count + 1, 0);
    for (std::size_t i = 0; i < count; ++i) {
      const std::uint32_t v = levels_[l][i].record;
      const VoxelRecord& r = tree_.voxels[v];
      p.children[i + 1] = p.children[i] + std::uint32_t(std::popcount(unsigned(r.childMask)));
      p.splits[i + 1] = p.splits[i] + (r.childMask != 0);
      p.contours[i + 1] = p.contours[i] + r.hasContour;
      p.colors[i + 1] = p.colors[i] + storesColor_[v];
      p.normals[i + 1] = p.normals[i] + storesNormal_[v];
    }
  }
}

void SlicePlanner::run(SliceSink& sink) const {
  plan({at_.rootLevel, at_.rootCoord, 0, 7}, at_.rootLevel + 1, 0, 1, at_.parentSlice, sink);
}

void SlicePlanner::runFrom(int level, std::uint32_t parentSlice, SliceSink& sink) const {
  if (level - 1 > topLevel()) return;
  plan({at_.rootLevel, at_.rootCoord, 0, 7}, level, 0, voxelsAt(level - 1).size(), parentSlice, sink);
}

std::vector<std::pair<std::uint32_t, glm::ivec3>> SlicePlanner::deepestVoxels() const {
  std::vector<std::pair<std::uint32_t, glm::ivec3>> out;
  for (const Voxel& v : levels_.back()) out.push_back({v.record, v.coord});
  return out;
}

std::vector<LevelTotals> SlicePlanner::totals() const {
  std::vector<LevelTotals> out(levels_.size());
  for (std::size_t l = 0; l < levels_.size(); ++l) {
    const Prefix& p = prefix_[l];
    out[l] = {levels_[l].size(), p.splits.back(), p.contours.back(), p.colors.back(), p.normals.back()};
  }
  return out;
}

void SlicePlanner::addCells(const std::vector<std::vector<LevelTotals>>& cells) {
  std::size_t depth = 0;
  for (const auto& t : cells) depth = std::max(depth, t.size());
  cellPrefix_.assign(depth, {});
  for (std::size_t k = 0; k < depth; ++k) {
    CellPrefix& p = cellPrefix_[k];
    for (auto* v : {&p.voxels, &p.splits, &p.children, &p.contours, &p.colors, &p.normals})
      v->assign(cells.size() + 1, 0);
    for (std::size_t i = 0; i < cells.size(); ++i) {
      const LevelTotals here = k < cells[i].size() ? cells[i][k] : LevelTotals{};
      const std::uint64_t below = k + 1 < cells[i].size() ? cells[i][k + 1].voxels : 0;
      p.voxels[i + 1] = p.voxels[i] + here.voxels, p.splits[i + 1] = p.splits[i] + here.splits;
      p.children[i + 1] = p.children[i] + below, p.contours[i + 1] = p.contours[i] + here.contours;
      p.colors[i + 1] = p.colors[i] + here.colors, p.normals[i + 1] = p.normals[i] + here.normals;
    }
  }
}

SliceSections SlicePlanner::sectionsOfLevel(int level) const {
  if (level - 1 > topLevel()) return SliceSections(tree_.hasColors, tree_.hasNormals);
  return sections(level, 0, voxelsAt(level - 1).size());
}

// The head of the slice of level `level` over the parents [a, b) of level - 1.
SliceHead SlicePlanner::headOf(int level, std::size_t a, std::size_t b) const {
  SliceHead h{};
  h.magic = kSliceMagic;
  h.attachments = sliceAttachments(tree_.hasColors, tree_.hasNormals);
  if (level - 1 < topLevel()) {
    const Prefix& up = prefixAt(level - 1);
    const Prefix& here = prefixAt(level);
    const std::uint32_t ca = up.children[a], cb = up.children[b];
    h.parentCount = std::uint32_t(b - a);
    h.splitCount = up.splits[b] - up.splits[a];
    h.voxelCount = cb - ca;
    h.contourCount = here.contours[cb] - here.contours[ca];
    h.colorCount = here.colors[cb] - here.colors[ca];
    h.normalCount = here.normals[cb] - here.normals[ca];
    return h;
  }
  // Cells: the same cells [a, b) on every level. Runs this large split, so saturating counts are exact
  // enough to decide that.
  const auto k = std::size_t(level - 1 - topLevel());
  const auto count = [&](const std::vector<std::uint64_t>& prefix) {
    return std::uint32_t(std::min<std::uint64_t>(prefix[b] - prefix[a], 0xFFFFFFFFu));
  };
  const CellPrefix& up = cellPrefix_[k];
  h.parentCount = count(up.voxels), h.splitCount = count(up.splits), h.voxelCount = count(up.children);
  if (k + 1 < cellPrefix_.size()) {
    const CellPrefix& here = cellPrefix_[k + 1];
    h.contourCount = count(here.contours), h.colorCount = count(here.colors);
    h.normalCount = count(here.normals);
  }
  return h;
}

// The parents [a, b) of level - 1 give the voxels [first, second) of `level` (cells: the same cells).
std::pair<std::size_t, std::size_t> SlicePlanner::childRange(int level, std::size_t a, std::size_t b) const {
  if (level - 1 >= topLevel()) return {a, b};
  const Prefix& up = prefixAt(level - 1);
  return {up.children[a], up.children[b]};
}

// The sub-cube of `cubeLevel` holding parent i of `level` (a cell's cube contains all of its voxels).
glm::ivec3 SlicePlanner::subCube(int level, std::size_t i, int cubeLevel) const {
  const int parentLevel = std::min(level - 1, topLevel());
  return voxelsAt(parentLevel)[i].coord >> (parentLevel - cubeLevel);
}

// The slices of `run` from voxel level `level` on; its parents are [a, b) of level - 1.
void SlicePlanner::plan(const Run& run, int level, std::size_t a, std::size_t b, std::uint32_t parentSlice,
                        SliceSink& sink) const {
  if (level > deepestLevel()) return;
  const SliceHead head = headOf(level, a, b);
  if (head.voxelCount == 0) return;
  const bool fromCells = level > topLevel();
  if (fromCells && run.cubeLevel >= topLevel()) {
    sink.delegate(a, level, parentSlice);  // within one cell: its own subtree plans the rest
    return;
  }
  const bool wholeCube = isWholeCube(run.firstSlot, run.lastSlot);
  if (sliceRawBytes(head) > sliceBytes_ && (!wholeCube || run.cubeLevel < level - 1)) {
    split(run, level, a, b, parentSlice, sink);
    return;
  }
  SliceInfo info;
  info.cubeLevel = run.cubeLevel;
  info.cubeCoord = run.cube;
  info.firstSlot = std::uint8_t(run.firstSlot), info.lastSlot = std::uint8_t(run.lastSlot);
  info.voxelLevel = level;
  info.parentCount = head.parentCount;
  info.voxelCount = head.voxelCount;
  info.contourCount = head.contourCount;
  info.colorCount = head.colorCount;
  info.normalCount = head.normalCount;
  info.parentSlice = parentSlice;
  const std::uint32_t id =
      fromCells ? sink.reserve(info, head, a, b) : sink.emit(encodeSlice(head, sections(level, a, b)), info);
  const auto [ca, cb] = childRange(level, a, b);
  plan(run, level + 1, ca, cb, id, sink);
}

// Splits a run whose level `level` exceeds the slice size: its sub-cubes, in Morton order (their parents
// are contiguous runs of [a, b)), are packed into groups that each fit; a group of one sub-cube becomes
// that sub-cube's own run, which packs its own sub-cubes in turn where it still does not fit.
void SlicePlanner::split(const Run& run, int level, std::size_t a, std::size_t b, std::uint32_t parentSlice,
                         SliceSink& sink) const {
  struct Part {
    int slot;
    std::size_t a, b;
  };
  std::vector<Part> parts;
  for (std::size_t i = a; i < b;) {
    const glm::ivec3 sub = subCube(level, i, run.cubeLevel + 1);
    std::size_t j = i;
    while (j < b && subCube(level, j, run.cubeLevel + 1) == sub) ++j;
    // A cell without voxels on level - 1 (all stopped above it) is no part: a tree's parents give none for
    // its sub-cube, and both must pack the same runs.
    if (headOf(level, i, j).parentCount > 0) parts.push_back({childSlot(sub), i, j});
    i = j;
  }
  // Even shares: a run of n slices' worth closes each group near 1/n of it instead of filling groups to
  // the slice size and leaving a small last one.
  const double total = double(sliceRawBytes(headOf(level, a, b)));
  const double share = total / std::ceil(total / double(sliceBytes_));
  for (std::size_t first = 0; first < parts.size();) {
    std::size_t last = first;
    while (last + 1 < parts.size()) {
      const double now = double(sliceRawBytes(headOf(level, parts[first].a, parts[last].b)));
      const double grown = double(sliceRawBytes(headOf(level, parts[first].a, parts[last + 1].b)));
      if (grown > double(sliceBytes_) || std::abs(grown - share) > std::abs(now - share)) break;
      ++last;
    }
    const Part& p = parts[first];
    if (first == last)
      plan({run.cubeLevel + 1, childCoord(run.cube, p.slot), 0, 7}, level, p.a, p.b, parentSlice, sink);
    else
      plan({run.cubeLevel, run.cube, p.slot, parts[last].slot}, level, p.a, parts[last].b, parentSlice, sink);
    first = last + 1;
  }
}

// Level `level` of the parents [a, b) of level - 1 (in the tree).
SliceSections SlicePlanner::sections(int level, std::size_t a, std::size_t b) const {
  SliceSections out(tree_.hasColors, tree_.hasNormals);
  const std::vector<Voxel>& parents = voxelsAt(level - 1);
  // Children follow their parents' order: walk both.
  const std::uint32_t ca = prefixAt(level - 1).children[a];
  const Voxel* child = level - 1 < topLevel() ? voxelsAt(level).data() + ca : nullptr;
  // The scene's root voxel has no contour in the store (the header holds its attributes only): readers
  // predict its children's contours without one, and so must this.
  const bool parentContours = level - 1 > 0;
  std::array<SliceChild, 8> children;
  for (std::size_t p = a; p < b; ++p) {
    const std::uint32_t parent = parents[p].record;
    const VoxelRecord& up = tree_.voxels[parent];
    const int count = std::popcount(unsigned(up.childMask));
    for (int k = 0; k < count; ++k) {
      const std::uint32_t v = (child++)->record;
      const VoxelRecord& r = tree_.voxels[v];
      children[std::size_t(k)] = {r.hasContour,          r.contour,
                                  storesColor_[v] != 0,  effectiveColor_[v],
                                  storesNormal_[v] != 0, effectiveNormal_[v]};
    }
    out.addParent({up.childMask, parentContours && up.hasContour, up.contour, effectiveNormal_[parent]},
                  std::span(children.data(), std::size_t(count)));
  }
  assert(child == nullptr || child == voxelsAt(level).data() + prefixAt(level - 1).children[b]);
  return out;
}

}  // namespace svo
