#include "split.hpp"

#include <algorithm>
#include <functional>
#include <limits>
#include <map>
#include <numeric>

#include "spokemesh/count_select.hpp"
#include "spokemesh/space_split.hpp"

namespace spokemesh::mpi {

namespace {

Status duplicate(const std::string& source, std::uint64_t a, std::uint64_t b) {
  return invalid_argument(source + ": points " + std::to_string(std::min(a, b)) + " and " +
                          std::to_string(std::max(a, b)) +
                          " are equal (spokemesh-mpi does not merge duplicates: remove them, or mesh on one process "
                          "with spokemesh mesh --merge-duplicates)");
}

// Proposal records on the wire: count, id, d coordinates.
void put_proposal(std::vector<char>& out, const CountSelect::Proposal& p, int d) {
  put<std::uint64_t>(out, p.count);
  put<std::uint64_t>(out, p.key.id);
  for (int c = 0; c < d; ++c) put<double>(out, p.count != 0 ? p.key.coords[static_cast<std::size_t>(c)] : 0.0);
}
CountSelect::Proposal get_proposal(const char*& at, int d) {
  CountSelect::Proposal p;
  p.count = get<std::uint64_t>(at);
  p.key.id = get<std::uint64_t>(at);
  p.key.coords.resize(static_cast<std::size_t>(d));
  for (int c = 0; c < d; ++c) p.key.coords[static_cast<std::size_t>(c)] = get<double>(at);
  return p;
}

}  // namespace

namespace {

// The bounding box of every node (d lows, d highs each) over all ranks' points:
// node_of[k] is point k's node, -1 or >= nodes for none. Lows and negated highs, one
// MIN reduction.
std::vector<double> node_boxes(Comm& comm, const Points& mine, const std::vector<std::int32_t>& node_of,
                               std::size_t nodes) {
  const auto dd = static_cast<std::size_t>(mine.d);
  std::vector<double> box(nodes * 2 * dd, std::numeric_limits<double>::infinity());
  for (std::uint32_t k = 0; k < mine.size(); ++k) {
    if (node_of[k] < 0 || static_cast<std::size_t>(node_of[k]) >= nodes) continue;
    double* b = &box[static_cast<std::size_t>(node_of[k]) * 2 * dd];
    for (std::size_t c = 0; c < dd; ++c) {
      b[c] = std::min(b[c], mine.point(k)[c]);
      b[dd + c] = std::min(b[dd + c], -mine.point(k)[c]);
    }
  }
  comm.allreduce(box, MPI_MIN);
  for (std::size_t a = 0; a < nodes; ++a) {
    for (std::size_t c = 0; c < dd; ++c) box[a * 2 * dd + dd + c] = -box[a * 2 * dd + dd + c];
  }
  return box;
}

// The widest side of each box, the lowest axis among equals (SpaceSplit's rule).
std::vector<int> widest_axes(const std::vector<double>& box, std::size_t nodes, int d) {
  const auto dd = static_cast<std::size_t>(d);
  std::vector<int> axis(nodes, 0);
  for (std::size_t a = 0; a < nodes; ++a) {
    const double* lo = &box[a * 2 * dd];
    const double* hi = lo + dd;
    for (int c = 1; c < d; ++c) {
      const auto k = static_cast<std::size_t>(c), best = static_cast<std::size_t>(axis[a]);
      if (hi[k] - lo[k] > hi[best] - lo[best]) axis[a] = c;
    }
  }
  return axis;
}

// The k[a]-th point along its axis of every node a (members[a]: the rank's points of it),
// all nodes in lockstep: a round is one gather and one sum.
std::vector<CountSelect::Key> joint_medians(Comm& comm, const Points& mine,
                                            const std::vector<std::vector<std::uint32_t>>& members,
                                            const std::vector<int>& axis, std::vector<std::uint64_t> k, int& rounds) {
  const int d = mine.d;
  const std::size_t m = members.size();
  std::vector<CountSelect> selects;
  selects.reserve(m);
  for (std::size_t a = 0; a < m; ++a) selects.emplace_back(d, axis[a], mine.coords, mine.ids, members[a]);
  std::vector<CountSelect::Key> pivot(m);
  std::vector<char> found(m, 0);
  for (;;) {
    std::vector<std::size_t> pending;
    for (std::size_t a = 0; a < m; ++a) {
      if (found[a] == 0) pending.push_back(a);
    }
    if (pending.empty()) break;
    ++rounds;
    std::vector<char> bytes;
    for (const std::size_t a : pending) put_proposal(bytes, selects[a].propose(), d);
    std::vector<std::uint64_t> sizes;
    const std::vector<char> all = comm.allgather_bytes(bytes, sizes);
    std::vector<std::vector<CountSelect::Proposal>> proposals(pending.size());
    const char* at = all.data();
    for (int r = 0; r < comm.size; ++r) {
      for (std::size_t i = 0; i < pending.size(); ++i) proposals[i].push_back(get_proposal(at, d));
    }
    std::vector<CountSelect::Key> pivots(pending.size());
    std::vector<std::uint64_t> below_at(2 * pending.size());
    for (std::size_t i = 0; i < pending.size(); ++i) {
      pivots[i] = CountSelect::pivot_of(proposals[i], axis[pending[i]]);
      const CountSelect::Counts c = selects[pending[i]].count(pivots[i]);
      below_at[2 * i] = c.below;
      below_at[2 * i + 1] = c.at;
    }
    comm.allreduce(below_at, MPI_SUM);
    for (std::size_t i = 0; i < pending.size(); ++i) {
      const std::size_t a = pending[i];
      const CountSelect::Side side = CountSelect::decide(k[a], {below_at[2 * i], below_at[2 * i + 1]});
      if (side == CountSelect::Side::kFound) {
        found[a] = 1;
        pivot[a] = pivots[i];
      } else {
        selects[a].narrow(pivots[i], side);
      }
    }
  }
  return pivot;
}

// INVALID_ARGUMENT (every rank the same) when a cut separates two equal points. The
// left side is every point before the pivot; two equal points are neighbours in every
// axis's order, so a cut can only separate equal points as the left side's last and
// the pivot: each rank offers its last left point.
Status check_cuts(Comm& comm, const Points& mine, const std::vector<std::vector<std::uint32_t>>& members,
                  const std::vector<int>& axis, const std::vector<CountSelect::Key>& pivot, const std::string& source) {
  const int d = mine.d;
  const std::size_t m = members.size();
  std::vector<char> last_left;
  for (std::size_t a = 0; a < m; ++a) {
    std::int64_t best = -1;
    for (const std::uint32_t kk : members[a]) {
      if (!before_along(axis[a], d, mine.point(kk), mine.ids[kk], pivot[a].coords.data(), pivot[a].id)) continue;
      if (best < 0 || before_along(axis[a], d, mine.point(static_cast<std::size_t>(best)),
                                   mine.ids[static_cast<std::size_t>(best)], mine.point(kk), mine.ids[kk])) {
        best = kk;
      }
    }
    CountSelect::Proposal p;
    if (best >= 0) {
      p.count = 1;
      p.key.id = mine.ids[static_cast<std::size_t>(best)];
      p.key.coords.assign(mine.point(static_cast<std::size_t>(best)), mine.point(static_cast<std::size_t>(best)) + d);
    }
    put_proposal(last_left, p, d);
  }
  std::vector<std::uint64_t> sizes;
  const std::vector<char> lasts = comm.allgather_bytes(last_left, sizes);
  const char* at = lasts.data();
  std::vector<CountSelect::Proposal> last(m);
  for (int r = 0; r < comm.size; ++r) {
    for (std::size_t a = 0; a < m; ++a) {
      const CountSelect::Proposal p = get_proposal(at, d);
      if (p.count == 0) continue;
      if (last[a].count == 0 || CountSelect::before(last[a].key, p.key, axis[a])) last[a] = p;
    }
  }
  for (std::size_t a = 0; a < m; ++a) {
    if (last[a].count != 0 && last[a].key.coords == pivot[a].coords)
      return duplicate(source, last[a].key.id, pivot[a].id);
  }
  return Status::ok();
}

// One level of the joint split: every node above `target` points is cut at its median
// along its widest side, its children replacing it (left then right: the list stays in
// sweep order). counts: the nodes' sizes; node_of: each of the rank's points' node.
// False when no node is above target.
Result<bool> split_level(Comm& comm, const Points& mine, std::uint64_t target, std::vector<std::uint64_t>& counts,
                         std::vector<std::int32_t>& node_of, TopSplit& out, const std::string& source) {
  std::vector<std::uint32_t> active;
  for (std::uint32_t i = 0; i < counts.size(); ++i) {
    if (counts[i] > target) active.push_back(i);
  }
  if (active.empty()) return false;
  ++out.joint_levels;
  const std::size_t m = active.size();
  std::vector<int> slot(counts.size(), -1);
  for (std::size_t a = 0; a < m; ++a) slot[active[a]] = static_cast<int>(a);
  std::vector<std::vector<std::uint32_t>> members(m);
  std::vector<std::int32_t> slot_of(mine.size(), -1);
  for (std::uint32_t k = 0; k < mine.size(); ++k) {
    slot_of[k] = slot[static_cast<std::size_t>(node_of[k])];
    if (slot_of[k] >= 0) members[static_cast<std::size_t>(slot_of[k])].push_back(k);
  }
  const std::vector<int> axis = widest_axes(node_boxes(comm, mine, slot_of, m), m, mine.d);
  std::vector<std::uint64_t> half(m);
  for (std::size_t a = 0; a < m; ++a) half[a] = counts[active[a]] / 2;
  const std::vector<CountSelect::Key> pivot = joint_medians(comm, mine, members, axis, half, out.select_rounds);
  if (Status s = check_cuts(comm, mine, members, axis, pivot, source); !s.is_ok()) return s;
  std::vector<std::uint64_t> next;
  std::vector<std::uint32_t> renumber(counts.size());
  for (std::uint32_t i = 0; i < counts.size(); ++i) {
    renumber[i] = static_cast<std::uint32_t>(next.size());
    if (slot[i] < 0) {
      next.push_back(counts[i]);
    } else {
      next.push_back(counts[i] / 2);
      next.push_back(counts[i] - counts[i] / 2);
    }
  }
  for (std::uint32_t kk = 0; kk < mine.size(); ++kk) {
    const auto i = static_cast<std::size_t>(node_of[kk]);
    auto to = static_cast<std::int32_t>(renumber[i]);
    if (slot[i] >= 0) {
      const auto a = static_cast<std::size_t>(slot[i]);
      if (!before_along(axis[a], mine.d, mine.point(kk), mine.ids[kk], pivot[a].coords.data(), pivot[a].id)) ++to;
    }
    node_of[kk] = to;
  }
  counts.swap(next);
  return true;
}

// The nodes' boxes, starts and owners: consecutive nodes to each rank, a node to the
// rank its middle position falls to.
void place_nodes(Comm& comm, const Points& mine, const std::vector<std::int32_t>& node_of,
                 const std::vector<std::uint64_t>& counts, std::uint64_t n, TopSplit& out) {
  const auto dd = static_cast<std::size_t>(mine.d);
  const std::size_t nodes = counts.size();
  const std::vector<double> box = node_boxes(comm, mine, node_of, nodes);
  out.nodes.resize(nodes);
  std::uint64_t start = 0;
  for (std::size_t i = 0; i < nodes; ++i) {
    TopNode& t = out.nodes[i];
    t.count = counts[i];
    t.start = start;
    // (n < 2^32 and P < 2^20: the product fits 64 bits.)
    const std::uint64_t middle = (2 * start + t.count) * static_cast<std::uint64_t>(comm.size);
    t.owner = static_cast<int>(std::min<std::uint64_t>(middle / (2 * n), static_cast<std::uint64_t>(comm.size - 1)));
    t.box.assign(box.begin() + static_cast<std::ptrdiff_t>(i * 2 * dd),
                 box.begin() + static_cast<std::ptrdiff_t>((i + 1) * 2 * dd));
    start += t.count;
  }
}

// Each point to its node's owner (node, index, coordinates), arriving grouped by node
// in index order: out.owned, out.owned_nodes, out.piece_ends. Frees `mine`.
void send_to_owners(Comm& comm, Points& mine, std::vector<std::int32_t>& node_of, TopSplit& out) {
  const int d = mine.d;
  const auto dd = static_cast<std::size_t>(d);
  // (Records sized first and copied in place: appends of a few bytes each were a third
  // of the exchange's time.)
  const std::size_t record = 4 + 8 + 8 * dd;
  std::vector<std::vector<char>> outgoing(static_cast<std::size_t>(comm.size));
  {
    std::vector<std::size_t> bytes(outgoing.size(), 0);
    for (std::uint32_t kk = 0; kk < mine.size(); ++kk)
      bytes[static_cast<std::size_t>(out.nodes[static_cast<std::size_t>(node_of[kk])].owner)] += record;
    for (std::size_t r = 0; r < outgoing.size(); ++r) outgoing[r].resize(bytes[r]);
    std::fill(bytes.begin(), bytes.end(), 0);
    for (std::uint32_t kk = 0; kk < mine.size(); ++kk) {
      const auto node = static_cast<std::uint32_t>(node_of[kk]);
      const auto r = static_cast<std::size_t>(out.nodes[node].owner);
      char* o = outgoing[r].data() + bytes[r];
      bytes[r] += record;
      std::memcpy(o, &node, 4);
      std::memcpy(o + 4, &mine.ids[kk], 8);
      std::memcpy(o + 12, mine.point(kk), 8 * dd);
    }
  }
  mine = Points{};
  node_of = {};
  const std::vector<char> in = comm.alltoall_bytes(outgoing);
  outgoing = {};
  const std::size_t got = in.size() / record;
  struct Arrival {
    std::uint32_t node;
    std::uint64_t id;
    std::size_t at;
  };
  std::vector<Arrival> arrivals(got);
  for (std::size_t i = 0; i < got; ++i) {
    const char* at = in.data() + i * record;
    arrivals[i].node = get<std::uint32_t>(at);
    arrivals[i].id = get<std::uint64_t>(at);
    arrivals[i].at = i * record + 12;
  }
  std::sort(arrivals.begin(), arrivals.end(),
            [](const Arrival& a, const Arrival& b) { return a.node != b.node ? a.node < b.node : a.id < b.id; });
  out.owned.d = d;
  out.owned.coords.resize(got * dd);
  out.owned.ids.resize(got);
  for (std::size_t i = 0; i < got; ++i) {
    std::memcpy(&out.owned.coords[i * dd], in.data() + arrivals[i].at, 8 * dd);
    out.owned.ids[i] = arrivals[i].id;
    if (i == 0 || arrivals[i].node != arrivals[i - 1].node) out.owned_nodes.push_back(arrivals[i].node);
    if (i + 1 == got || arrivals[i + 1].node != arrivals[i].node)
      out.piece_ends.push_back(static_cast<std::uint32_t>(i + 1));
  }
}

// Equal points that no joint cut separated are both on one rank: neighbours in
// lexicographic order.
Status check_owned_duplicates(const Points& owned, const std::string& source) {
  const int d = owned.d;
  std::vector<std::uint32_t> lex(owned.size());
  std::iota(lex.begin(), lex.end(), 0u);
  std::sort(lex.begin(), lex.end(), [&](std::uint32_t a, std::uint32_t b) {
    return before_along(0, d, owned.point(a), owned.ids[a], owned.point(b), owned.ids[b]);
  });
  for (std::size_t i = 1; i < lex.size(); ++i) {
    if (std::equal(owned.point(lex[i - 1]), owned.point(lex[i - 1]) + d, owned.point(lex[i]))) {
      return duplicate(source, owned.ids[lex[i - 1]], owned.ids[lex[i]]);
    }
  }
  return Status::ok();
}

}  // namespace

Result<TopSplit> split_across_ranks(Comm& comm, Points mine, std::uint64_t n, std::uint64_t target,
                                    const std::string& source) {
  TopSplit out;
  std::vector<std::uint64_t> counts{n};
  std::vector<std::int32_t> node_of(mine.size(), 0);
  for (;;) {
    auto more = split_level(comm, mine, target, counts, node_of, out, source);
    if (!more.is_ok()) return more.status();  // every rank found the same
    if (!more.value()) break;
  }
  place_nodes(comm, mine, node_of, counts, n, out);
  send_to_owners(comm, mine, node_of, out);
  if (Status s = comm.agree(check_owned_duplicates(out.owned, source)); !s.is_ok()) return s;
  return out;
}

std::vector<std::uint32_t> sweep_piece_ends(const TopSplit& split, int rank) {
  if (split.nodes.empty()) return {};
  // The top nodes by their first position; the recursion halves [b, e) by counts
  // ([b, b + (e - b) / 2) left), exactly as the joint levels cut it, down to them.
  std::map<std::uint64_t, const TopNode*> by_start;
  std::uint64_t n = 0;
  for (const TopNode& node : split.nodes) {
    by_start[node.start] = &node;
    n = std::max(n, node.start + node.count);
  }
  std::vector<std::uint64_t> counts;  // the merged pieces' point counts, in order
  // Returns the rank owning all of [b, e), or -1; appends the maximal nodes wholly this
  // rank's below a node that is not.
  std::function<int(std::uint64_t, std::uint64_t, std::vector<std::uint64_t>&)> visit =
      [&](std::uint64_t b, std::uint64_t e, std::vector<std::uint64_t>& mine) -> int {
    if (const auto it = by_start.find(b); it != by_start.end() && it->second->start + it->second->count == e) {
      return it->second->owner;
    }
    if (e - b <= 1) return -1;  // not a node of the split (cannot happen)
    const std::uint64_t mid = b + (e - b) / 2;
    std::vector<std::uint64_t> left, right;
    const int l = visit(b, mid, left), r = visit(mid, e, right);
    if (l >= 0 && l == r) return l;
    if (l == rank) left = {mid - b};
    if (r == rank) right = {e - mid};
    mine.insert(mine.end(), left.begin(), left.end());
    mine.insert(mine.end(), right.begin(), right.end());
    return -1;
  };
  if (visit(0, n, counts) == rank) counts = {n};
  std::vector<std::uint32_t> ends;
  std::uint64_t at = 0;
  for (const std::uint64_t c : counts) ends.push_back(static_cast<std::uint32_t>(at += c));
  // (Should the recursion not meet the top nodes, the top nodes themselves.)
  if (ends.empty() || ends.back() != split.owned.size()) return split.piece_ends;
  return ends;
}

}  // namespace spokemesh::mpi
