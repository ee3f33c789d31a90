// The messages of a build shared out over MPI, and the waits between them. Every rank runs the same binary
// (mpirun starts one program), so the messages are the structs' bytes.
#pragma once

#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

#include <mpi.h>

#include "cell_voxelizer.hpp"
#include "svo/store/block.hpp"

namespace svo::mpi {

enum Tag : int { kReportTag = 1, kAssignTag = 2, kStartTag = 3 };

// Rank 0 -> rank > 0, once: the cell level to bin the input for, or 0 when the job failed before.
struct Start {
  std::int32_t cellLevel = 0;
};

// What a rank has done so far; every report carries it, so rank 0 has each rank's totals at the end.
struct Totals {
  std::uint64_t cells = 0, peakResidentBytes = 0;
  double buildSeconds = 0.0;
};

// Rank > 0 -> rank 0: ready for a cell, a cell built (and spilled), or a failure (its message follows).
struct Report {
  enum Kind : std::int32_t { kReady, kBuilt, kFailed } kind = kReady;
  std::int64_t task = -1;
  VoxelRecord root;
  double weight = 0.0, color[4] = {}, normal[3] = {};
  std::uint64_t voxels = 0;
  Totals totals;
};

// Rank 0 -> rank > 0: a cell to build (its slabs, then where its triangles are binned, follow), or the end
// of the job.
struct Assignment {
  enum Kind : std::int32_t { kTask, kStop, kStopFailed } kind = kStop;
  std::int32_t cellLevel = 0;
  std::int64_t task = -1;
  std::int32_t coord[3] = {};
  std::uint64_t slabCount = 0, partCount = 0;
};

inline std::vector<char> pack(const Start& s) {
  std::vector<char> out(sizeof s);
  std::memcpy(out.data(), &s, sizeof s);
  return out;
}

inline std::vector<char> pack(const Report& r, const std::string& error = {}) {
  std::vector<char> out(sizeof r + error.size());
  std::memcpy(out.data(), &r, sizeof r);
  std::memcpy(out.data() + sizeof r, error.data(), error.size());
  return out;
}

inline std::vector<char> pack(const Assignment& a, const CellTask* task = nullptr) {
  const std::size_t slabBytes = task ? task->slabs.size() * sizeof(geom::Slab) : 0;
  const std::size_t partBytes = task ? task->parts.size() * sizeof(CellPart) : 0;
  std::vector<char> out(sizeof a + slabBytes + partBytes);
  std::memcpy(out.data(), &a, sizeof a);
  if (slabBytes) std::memcpy(out.data() + sizeof a, task->slabs.data(), slabBytes);
  if (partBytes) std::memcpy(out.data() + sizeof a + slabBytes, task->parts.data(), partBytes);
  return out;
}

// The cell an assignment hands out, from the bytes after it.
inline CellTask unpackTask(const Assignment& a, const std::vector<char>& rest) {
  CellTask task;
  task.coord = glm::ivec3(a.coord[0], a.coord[1], a.coord[2]);
  const std::size_t slabBytes = a.slabCount * sizeof(geom::Slab), partBytes = a.partCount * sizeof(CellPart);
  if (rest.size() != slabBytes + partBytes) throw std::runtime_error("MPI: a cell's assignment is cut");
  task.slabs.resize(a.slabCount);
  task.parts.resize(a.partCount);
  if (slabBytes) std::memcpy(task.slabs.data(), rest.data(), slabBytes);
  if (partBytes) std::memcpy(task.parts.data(), rest.data() + slabBytes, partBytes);
  return task;
}

// The struct at the front of a message, and what follows it.
template <class T>
T front(const std::vector<char>& message, std::vector<char>* rest = nullptr) {
  T value;
  if (message.size() < sizeof value) throw std::runtime_error("MPI: a message is truncated");
  std::memcpy(&value, message.data(), sizeof value);
  if (rest) rest->assign(message.begin() + sizeof value, message.end());
  return value;
}

void send(int to, Tag tag, const std::vector<char>& message);
// The next message with `tag` from `from` (or MPI_ANY_SOURCE), waiting without spinning a core; `sender`
// gets who sent it.
std::vector<char> receive(int from, Tag tag, int* sender = nullptr);
// The same without waiting: false when none has arrived.
bool tryReceive(int from, Tag tag, std::vector<char>& message, int& sender);
// Sleeps one poll interval (waiting ranks poll rather than block: MPI's blocking waits spin a core).
void pause();

std::uint64_t peakResidentBytes();

}  // namespace svo::mpi
