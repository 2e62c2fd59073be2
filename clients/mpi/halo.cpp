#include "halo.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <memory>

#include "spokemesh/certify.hpp"

namespace spokemesh::mpi {

Halo::Halo(Comm& comm, const TopSplit& split, std::vector<double> global_box, double first_halo_factor)
    : comm_(comm), split_(split), d_(split.owned.d), global_(std::move(global_box)) {
  const std::size_t pieces = split.owned_nodes.size();
  held_.resize(pieces);
  depth_.resize(pieces);
  for (std::size_t p = 0; p < pieces; ++p) {
    const std::vector<double>& b = split.nodes[split.owned_nodes[p]].box;
    // The node's mean spacing (of its extent, for a flat node).
    double volume = 1, widest = 0;
    for (int c = 0; c < d_; ++c) {
      const double side = b[static_cast<std::size_t>(d_ + c)] - b[static_cast<std::size_t>(c)];
      widest = std::max(widest, side);
      volume *= side;
    }
    const double count = static_cast<double>(split.nodes[split.owned_nodes[p]].count);
    const double spacing = volume > 0 ? std::pow(volume / count, 1.0 / d_) : widest / count;
    depth_[p] = first_halo_factor * std::max(spacing, widest * 1e-9);
    held_[p] = grown(p);
  }
}

std::vector<double> Halo::unheld(std::size_t piece) const {
  std::vector<double> out;
  const std::vector<double>& q = held_[piece];
  const auto d = static_cast<std::size_t>(d_);
  for (const mpi::TopNode& node : split_.nodes) {
    if (node.owner == comm_.rank) continue;
    std::vector<double> rest = node.box;  // what is left of the node's box
    bool empty = false;
    for (std::size_t c = 0; c < d && !empty; ++c) {
      if (rest[c] < q[c]) {  // the part below the held box along c
        std::vector<double> part = rest;
        part[d + c] = std::min(rest[d + c], q[c]);
        out.insert(out.end(), part.begin(), part.end());
      }
      if (rest[d + c] > q[d + c]) {
        std::vector<double> part = rest;
        part[c] = std::max(rest[c], q[d + c]);
        out.insert(out.end(), part.begin(), part.end());
      }
      rest[c] = std::max(rest[c], q[c]);
      rest[d + c] = std::min(rest[d + c], q[d + c]);
      empty = rest[c] > rest[d + c];
    }
  }
  return out;
}

std::vector<double> Halo::requests_of(const std::vector<std::size_t>& pieces) const {
  std::vector<double> out;
  for (const std::size_t p : pieces) out.insert(out.end(), held_[p].begin(), held_[p].end());
  return out;
}

void Halo::fetch(const std::vector<double>& boxes, const std::vector<double>& facets, const std::vector<double>& balls,
                 const KdTree* held_tree, const std::vector<std::uint32_t>* own_of_held) {
  const auto d = static_cast<std::size_t>(d_);
  std::vector<char> mine;
  for (const std::vector<double>* list : {&boxes, &facets, &balls}) {
    mpi::put<std::uint64_t>(mine, list->size());
    for (const double v : *list) mpi::put<double>(mine, v);
  }
  std::vector<std::uint64_t> sizes;
  const std::vector<char> all = comm_.allgather_bytes(mine, sizes);
  std::vector<std::vector<char>> outgoing(static_cast<std::size_t>(comm_.size));
  const Points& own = split_.owned;
  if (sent_.empty()) sent_.resize(static_cast<std::size_t>(comm_.size));
  // A tree of this rank's own points answers the requests; built for this exchange
  // and dropped after it, when the round's own structures are gone (it would
  // otherwise be the largest thing a rank keeps between rounds).
  bool asked = false;
  for (int r = 0; r < comm_.size; ++r) asked |= r != comm_.rank && sizes[static_cast<std::size_t>(r)] > 16;
  PointSet own_points;
  std::unique_ptr<KdTree> own_tree;
  const KdTree* search = held_tree;
  if (search == nullptr && asked && own.size() != 0) {
    own_points = PointSet(d_, std::vector<double>(own.coords));
    own_tree = std::make_unique<KdTree>(own_points);
    search = own_tree.get();
  }
  // The rank's own index of a point of the searched tree, or kNone.
  auto own_index = [&](std::uint32_t id) { return held_tree == nullptr ? id : (*own_of_held)[id]; };
  const char* at = all.data();
  for (int r = 0; r < comm_.size; ++r) {
    std::vector<double> box_list(mpi::get<std::uint64_t>(at));
    for (double& v : box_list) v = mpi::get<double>(at);
    std::vector<double> facet_list(mpi::get<std::uint64_t>(at));
    for (double& v : facet_list) v = mpi::get<double>(at);
    std::vector<double> ball_list(mpi::get<std::uint64_t>(at));
    for (double& v : ball_list) v = mpi::get<double>(at);
    if (r == comm_.rank || search == nullptr) continue;
    std::vector<char>& sent = sent_[static_cast<std::size_t>(r)];
    if (sent.empty()) sent.assign(own.size(), 0);
    std::vector<char>& o = outgoing[static_cast<std::size_t>(r)];
    auto give = [&](std::uint32_t id) {
      const std::uint32_t k = own_index(id);
      if (k == kNone || sent[k] != 0) return;
      sent[k] = 1;
      mpi::put<std::uint64_t>(o, own.ids[k]);
      for (std::size_t c = 0; c < d; ++c) mpi::put<double>(o, own.point(k)[c]);
    };
    for (std::size_t b = 0; b + 2 * d <= box_list.size(); b += 2 * d) {
      const double* q = &box_list[b];
      search->find_first(
          [&](const float* lo, const float* hi) {
            for (std::size_t c = 0; c < d; ++c) {
              if (static_cast<double>(hi[c]) < q[c] || static_cast<double>(lo[c]) > q[d + c]) return false;
            }
            return true;
          },
          [&](std::uint32_t k, const double* x) {
            if (contains(q, x)) give(k);
            return false;  // every one, not the first
          });
    }
    // Balls: every point within the radius, and a relative 1e-9 more (beyond the
    // radius search's rounding), so that no point on a sphere is missed.
    std::vector<std::pair<std::uint32_t, double>> found;
    for (std::size_t b = 0; b + d + 1 <= ball_list.size(); b += d + 1) {
      const double radius = ball_list[b + d] * (1 + 1e-9);
      search->within(&ball_list[b], radius * radius, found);
      for (const auto& [k, dist2] : found) give(k);
    }
    const std::size_t facet_words = (d + 3) * d;
    for (std::size_t f = 0; f + facet_words <= facet_list.size(); f += facet_words) {
      std::array<const double*, 3> vertex{};
      for (std::size_t v = 0; v < d; ++v) vertex[v] = &facet_list[f + v * d];
      const double* inner = &facet_list[f + d * d];
      const double* region = &facet_list[f + (d + 1) * d];
      search->find_first(
          [&](const float* lo, const float* hi) {
            double box[6];
            for (std::size_t c = 0; c < d; ++c) {
              box[c] = lo[c];
              box[d + c] = hi[c];
              if (box[d + c] < region[c] || box[c] > region[d + c]) return false;
            }
            return StarCertifier::may_be_beyond(d_, vertex.data(), inner, box);
          },
          [&](std::uint32_t k, const double* x) {
            if (contains(region, x) && StarCertifier::may_be_beyond_point(d_, vertex.data(), inner, x)) give(k);
            return false;
          });
    }
  }
  const std::vector<char> in = comm_.alltoall_bytes(outgoing);
  ghosts_.d = d_;
  for (const char* p = in.data(); p < in.data() + in.size();) {
    ghosts_.ids.push_back(mpi::get<std::uint64_t>(p));
    for (int c = 0; c < d_; ++c) ghosts_.coords.push_back(mpi::get<double>(p));
  }
}

std::vector<double> Halo::grown(std::size_t p) const {
  std::vector<double> q = split_.nodes[split_.owned_nodes[p]].box;
  const auto d = static_cast<std::size_t>(d_);
  for (std::size_t c = 0; c < d; ++c) {
    q[c] = std::max(global_[c], q[c] - depth_[p]);
    q[d + c] = std::min(global_[d + c], q[d + c] + depth_[p]);
  }
  return q;
}

bool Halo::contains(const double* q, const double* x) const {
  const auto d = static_cast<std::size_t>(d_);
  for (std::size_t c = 0; c < d; ++c) {
    if (x[c] < q[c] || x[c] > q[d + c]) return false;
  }
  return true;
}

LocalSet gather_local(const TopSplit& split, const Points& ghosts) {
  const Points& own = split.owned;
  const std::size_t n_own = own.size(), total = n_own + ghosts.size();
  const auto d = static_cast<std::size_t>(own.d);
  std::vector<std::pair<std::uint64_t, std::int64_t>> order(total);  // (global, own k or -1 - ghost k)
  for (std::size_t k = 0; k < n_own; ++k) order[k] = {own.ids[k], static_cast<std::int64_t>(k)};
  for (std::size_t k = 0; k < ghosts.size(); ++k) order[n_own + k] = {ghosts.ids[k], -1 - static_cast<std::int64_t>(k)};
  std::sort(order.begin(), order.end());
  LocalSet out;
  std::vector<double> coords(total * d);
  out.global.resize(total);
  out.local_of_own.resize(n_own);
  out.piece_of.assign(total, -1);
  std::vector<std::int32_t> piece_of_own(n_own);
  std::uint32_t begin = 0;
  for (std::size_t p = 0; p < split.piece_ends.size(); ++p) {
    for (std::uint32_t k = begin; k < split.piece_ends[p]; ++k) piece_of_own[k] = static_cast<std::int32_t>(p);
    begin = split.piece_ends[p];
  }
  for (std::size_t i = 0; i < total; ++i) {
    out.global[i] = order[i].first;
    const double* from;
    if (order[i].second >= 0) {
      const auto k = static_cast<std::size_t>(order[i].second);
      from = own.point(k);
      out.local_of_own[k] = static_cast<std::uint32_t>(i);
      out.piece_of[i] = piece_of_own[k];
    } else {
      from = ghosts.point(static_cast<std::size_t>(-1 - order[i].second));
    }
    std::copy(from, from + d, &coords[i * d]);
  }
  out.points = PointSet(own.d, std::move(coords));
  return out;
}

}  // namespace spokemesh::mpi
