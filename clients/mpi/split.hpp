// The distributed form of SpaceSplit's top levels (docs/distributed.md): P ranks,
// each holding any part of the set, cut it together into nodes of at most `target`
// points, exactly the nodes SpaceSplit's recursion makes on one process, and deal the
// nodes out to the ranks in order, balanced by counts.
//
// Thread safety: collective; main thread only.
#pragma once

#include <cstdint>
#include <vector>

#include "comm.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh::mpi {

// Points as a rank holds them: d coordinates each (row-major) and their indices in
// the whole set.
struct Points {
  int d = 0;
  std::vector<double> coords;
  std::vector<std::uint64_t> ids;
  std::size_t size() const { return ids.size(); }
  const double* point(std::size_t k) const { return coords.data() + k * static_cast<std::size_t>(d); }
};

// A node of the whole set's split, as every rank knows it.
struct TopNode {
  std::uint64_t count = 0;
  std::uint64_t start = 0;  // its first position in the sweep order
  int owner = 0;            // the rank that meshes its points
  std::vector<double> box;  // tight bounding box: d lows, then d highs
};

struct TopSplit {
  std::vector<TopNode> nodes;  // in the sweep order
  // The rank's points grouped by node, nodes in order (a piece per owned node):
  // owned.ids[piece_ends[k - 1] .. piece_ends[k]) are the points of its k-th node.
  Points owned;
  std::vector<std::uint32_t> owned_nodes;  // node index of each piece
  std::vector<std::uint32_t> piece_ends;
  // The pieces merged into the largest nodes the rank owns whole (sweep_piece_ends):
  // the pieces its sweep takes, so that its regions are as large as one process's.
  std::vector<std::uint32_t> sweep_ends;
  int joint_levels = 0, select_rounds = 0;
};

// The rank's pieces merged into the largest nodes of the whole set's split that it
// owns entirely (a node whose every top node is this rank's), as ends into
// split.owned: a SpaceSplit over them gives the same positions as over the top nodes
// (each merged node is split as the whole set's recursion splits it), while its
// regions (nodes_of_at_most) may now span what were several pieces.
std::vector<std::uint32_t> sweep_piece_ends(const TopSplit& split, int rank);

// Cuts the set (every rank's `mine`) into nodes of at most `target` points, checks that
// no two points are equal (INVALID_ARGUMENT naming both, agreed by every rank), and
// sends each point to its node's owner. `source` names the input in messages.
Result<TopSplit> split_across_ranks(Comm& comm, Points mine, std::uint64_t n, std::uint64_t target,
                                    const std::string& source);

}  // namespace spokemesh::mpi
