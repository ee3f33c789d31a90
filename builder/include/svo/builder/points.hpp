// Point clouds (scans) as the builder sees them: read from PLY, Draco and .xyz files, normals estimated where
// the file has none, and voxelized into octree levels with contours fitted to each voxel's points.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include <glm/vec3.hpp>
#include <glm/vec4.hpp>

#include "svo/builder/build.hpp"

namespace svo {

struct PointCloud {
  std::vector<glm::dvec3> positions;  // world space, finite
  std::vector<glm::vec3> normals;  // per point, unit length or zero (unknown); empty when the file has none
  std::vector<glm::vec4> colors;   // per point linear RGBA in [0, 1]; empty when the file has none
  std::string format;              // what the file was read as
  std::uint64_t missing = 0;       // points the header declares that a truncated file lacks
};

// Whether `svo build` reads the file as a point cloud, by content: a .xyz file, a PLY whose header declares
// vertices and no faces, a Draco file encoding a point cloud.
bool isPointCloudFile(const std::filesystem::path& path);

// Reads a point cloud:
// - PLY, ASCII or binary (either byte order): the `vertex` element's x, y, z; nx, ny, nz when present; colors
//   from red, green, blue or diffuse_red, diffuse_green, diffuse_blue (integers scaled from their type's
//   range, floats taken as [0, 1]). Other elements and properties are skipped; a face element makes it a
//   mesh, not a point cloud. A file that ends inside the vertex records gives the complete ones before the
//   cut (PointCloud::missing counts the rest); one that ends before the first vertex is an error.
// - Draco (.drc) point clouds: POSITION, and NORMAL and COLOR when present.
// - .xyz text, one point per line, numbers separated by spaces, tabs or commas; `#` starts a comment. The
//   columns, the same on every line, are one of: x y z | x y z r g b | x y z r g b nx ny nz | x y z nx ny nz
//   (9 columns are colors then normals; 6 columns are colors when every value of columns 4-6 in the file is
//   an integer in 0..255 and any exceeds 1, else normals). Colors r g b are in 0..255.
// Colors are display (sRGB) values, made linear as mesh colors are. Throws std::runtime_error with one line
// naming the file and the problem: missing file, malformed header, truncated data, non-finite position, no
// points. A normal that is zero or not finite is unknown: zero in `normals`, for estimateNormals.
PointCloud loadPointCloud(const std::filesystem::path& path);

// What readPointCloud found in the file.
struct PointFileInfo {
  std::string format;
  bool normals = false, colors = false;  // whether the file has them (its batches carry them)
  std::uint64_t points = 0;              // read
  std::uint64_t missing = 0;             // as PointCloud::missing
};
// Takes each batch of points (positions, and normals and colors where the file has them), the index of its
// first point in the file and the fraction of the file read.
using PointBatch = std::function<void(const PointCloud& batch, std::uint64_t first, double fraction)>;
// loadPointCloud's points streamed in batches of at most 65536, in file order, never holding the file
// (except a .drc, which Draco decodes whole): the same values and the same errors, a non-finite position
// as soon as its batch is read. loadPointCloud gathers these batches.
PointFileInfo readPointCloud(const std::filesystem::path& path, const PointBatch& batch);

// What a scan's file holds, read as cheaply as its format allows: a PLY's header alone (`points` as declared,
// `missing` 0), other formats read through (readPointCloud without keeping the points). For deciding how to
// build before building; throws as readPointCloud does.
PointFileInfo surveyPointFile(const std::filesystem::path& path);

// Checks the cloud (finite positions, attribute counts matching) and throws naming `source` and
// the first bad point. loadPointCloud calls it.
void validatePointCloud(const PointCloud& cloud, const std::string& source);

// k of the k-nearest-neighbour tangent planes (Hoppe et al. 1992, "Surface reconstruction from unorganized
// points", sec. 3.2: the plane through a point's k nearest neighbours by principal component analysis; k is
// theirs to choose). Against assimp-testmodels' pond scan's own normals, k = 8, 16, 32, 64 give median
// angles of 13.1, 14.7, 17.0, 19.7 degrees: fewer neighbours follow the surface closer, but 16 still finds a
// plane where points lie in lines (scanner rows).
inline constexpr int kNormalNeighbours = 16;

struct NormalEstimate {
  std::size_t estimated = 0;   // points whose normal was computed
  std::size_t flipped = 0;     // of those, turned over by the orientation pass
  std::size_t components = 0;  // neighbour-graph components, each oriented from its own seed
};
// Fills in every zero (or missing) normal: the smallest-eigenvalue eigenvector of the covariance of the
// point's k nearest neighbours (itself included), then oriented consistently as Hoppe et al. orient theirs
// (sec. 3.3): along a minimum spanning tree of the symmetric k-nearest-neighbour graph weighted 1 - |ni.nj|,
// from a seed per connected component, the component's highest point (largest z), whose normal is turned to
// +z; each point takes the side of its tree parent. Normals the file gave are kept and seed their
// neighbours. Deterministic.
NormalEstimate estimateNormals(PointCloud& cloud, int neighbours = kNormalNeighbours);

// The typical spacing of the points on their surface, in world units: the side of the square of surface
// each point owns (density^-1/2). Each sampled point's k-th nearest neighbour (k = kNormalNeighbours, itself
// included) lies at r where k - 1 other points fill pi r^2, so density = (k - 1) / (pi r^2); the median over
// the sample. `sample` is every (total / sample.size())-th point of a cloud of `total` points: thinning a
// cloud keeps where its points lie and scales its density by sample/total, so the sample's spacing is scaled
// by sqrt(sample/total). On random samples of a sphere it gives 0.99 of the true spacing, on even (Fibonacci)
// ones 1.00 to 1.04.
double estimatePointSpacing(const std::vector<glm::dvec3>& sample, std::uint64_t total);
// Points a spacing estimate samples: the median of 2^16 samples is within 1% of the whole cloud's.
inline constexpr std::size_t kSpacingSamples = std::size_t(1) << 16;
// Every (n / kSpacingSamples)-th point of the cloud (all of a smaller one), then estimatePointSpacing.
double estimatePointSpacing(const PointCloud& cloud);

// How many point spacings wide the finest voxel must be for a scan to leave no holes (voxels no point falls
// in, through which rays pass). Swept on random (Poisson) samples of a sphere at 6 levels, three seeds each:
// a voxel of 2, 2.5, 3, 3.5, 4 spacings sealed the inside 0, 0, 2, 3, 3 times of 3; an even (Fibonacci)
// sampling seals from 2 on. Random is the worse case, and a surface sample's.
inline constexpr double kVoxelsPerSpacing = 3.5;
// The deepest level (1 to kMaxPointLevels) whose finest voxel is at least kVoxelsPerSpacing * spacing wide in
// the scene cube of `transform`.
int levelsForSpacing(double spacing, const SceneTransform& transform);

// Deepest octree a point cloud builds: a finest voxel's Morton code, 3 bits a level, fits in 64 bits.
inline constexpr int kMaxPointLevels = 21;
// Shallowest octree `--levels` may ask of a scan: out of core its cells lie at level 1 or deeper, above the
// finest.
inline constexpr int kMinPointLevels = 2;

// The point cloud's voxels in the octree frame of `transform`, `options.levels` deep: each point falls in one
// finest voxel; a voxel's color and normal are the means of its points' (normals summed as unit vectors);
// where options.contours, each voxel below the root gets the thinnest slab along its (stored) normal that
// holds all its points, kept as the mesh builder keeps a contour: when it trims at least
// options.leafContourMinReduction (finest voxels) or options.innerContourMinReduction (coarser ones) voxel
// widths off the voxel's cube as its ancestors' contours bound it (sec. 5.3). Needs normals for every point
// (estimateNormals). Deterministic, whatever the thread count.
VoxelTree voxelizePoints(const PointCloud& cloud, const SceneTransform& transform,
                         const BuildOptions& options, BuildStats* stats = nullptr);

// Throws unless voxelizePoints can build the cloud with these options (levels, points, a normal for each).
void checkPointBuild(const PointCloud& cloud, const BuildOptions& options);

// Resident bytes per point of the in-core scan build at its peak, beyond the program's own. Measured:
// `svo build`'s peak resident less `svo build --help`'s, per point, on 2M points of a random sphere: at 12
// levels (a finest voxel per point, 6.5M voxels) 350 B with normals estimated, 357 B with the file's; at the
// 7 levels the spacing fits, 308 B and 64 B. The largest, rounded up by a tenth; a --levels deeper than a
// voxel per point adds a chain of voxels per point that it does not count.
inline constexpr double kInCoreBytesPerPoint = 400.0;
// The in-core scan build's estimated peak, beyond the program's, for `points` points.
std::uint64_t estimateInCorePointBuildBytes(std::uint64_t points);
// How a scan build with no memory bound given runs: in core when the program (`processBytes`) and the in-core
// estimate fit `share`, else out of core within `share`.
struct PointBuildPlan {
  std::uint64_t inCoreBytes = 0;  // processBytes + estimateInCorePointBuildBytes
  bool outOfCore = false;
};
PointBuildPlan planPointBuild(std::uint64_t points, std::uint64_t processBytes, std::uint64_t share);

// The out-of-core scan build's depth, from the points' spacing and the scene cube (2 to kMaxPointLevels).
using PointLevelChoice = std::function<int(double spacing, const SceneTransform& transform)>;
struct PointStoreReport {
  OutOfCoreReport build;
  PointFileInfo file;
  double spacing = 0.0;                // estimatePointSpacing's, from the file's sample
  int levels = 0;                      // chosen
  std::uint64_t normalsEstimated = 0;  // cells' own points and halos
};
// Writes `store` from the scan at `input` within bounded memory, never holding its points: the file is read
// in batches (readPointCloud) once for its bounds and fingerprint, once for the spacing's sample and the
// points per cell of level 9 (from which the cell level: the shallowest whose fullest cell fits
// ooc.memoryBytes, unless ooc.cellLevel), once to bin every point into its cell in the work folder, with
// copies of the points within kHaloSpacings spacings of a neighbouring cell in that cell's halo. Normals are
// estimated cell by cell (estimateNormals over the cell's points and halo), breadth first from the highest
// point's cell, each cell's halo points from cells done before keeping their final normals, so that they
// orient the cell's as Hoppe's tree would. The levels above the cells come from the cells' sums and
// points, each cell's subtree from its points (spilled, resumable), and the store from both
// (StoreFileWriter::appendForest). With the file's normals for every point the octree (loadTree) is the
// in-core build's; with normals estimated the voxels are the same, their normals (and so contours) differ
// only where a cell's estimate differs from the whole cloud's. Cells are built one at a time, each on all
// threads.
PointStoreReport buildPointStore(const std::filesystem::path& input, BuildOptions options,
                                 const StoreWriteOptions& write, const OutOfCoreOptions& ooc,
                                 const std::filesystem::path& store, const PointLevelChoice& levels);

// The scene cube of the points (fitSceneCube of their bounds). Throws when they have no extent.
SceneTransform fitSceneCube(const PointCloud& cloud);

}  // namespace svo
