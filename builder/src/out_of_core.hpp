// The out-of-core build with its cells built by a given runner (a build shared out over MPI).
#pragma once

#include <filesystem>

#include "cell_voxelizer.hpp"
#include "svo/builder/build.hpp"

namespace svo {

// buildStore (build.hpp) with the cells built by `runner` and the pass over the input shared as `sharing`
// says (this process is its rank 0); the work folder is where the runner's cells are spilled
// (OutOfCoreOptions::workDir, or STORE.build) and the triangles binned (scratchOf).
OutOfCoreReport buildStore(const TriangleSource& source, const BuildOptions& options,
                           const StoreWriteOptions& write, const OutOfCoreOptions& ooc,
                           const std::filesystem::path& store, const CellRunner& runner,
                           const TopSharing& sharing = {});
std::filesystem::path scratchOf(const std::filesystem::path& work);
std::filesystem::path workFolderOf(const OutOfCoreOptions& ooc, const std::filesystem::path& store);

}  // namespace svo
