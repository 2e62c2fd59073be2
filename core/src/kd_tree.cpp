#include "spokemesh/kd_tree.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

namespace spokemesh {

namespace {

// The points' order along a Z-order (Morton) curve over a grid of at most 2^20 cells
// spanning their bounding box, by one counting sort. Only a memory layout: nanoflann's
// build partitions the index array over and over, reading each point's coordinates,
// and in this order those reads stay local (a shuffled 2-d million: 0.45 s -> 0.25 s).
// The tree's splits come from the subsets' bounding boxes, whatever their order.
std::vector<std::uint32_t> z_order(const PointSet& points) {
  const std::size_t n = points.size(), d = static_cast<std::size_t>(points.dimension());
  int total_bits = 0;
  while (total_bits < 20 && (std::size_t{1} << total_bits) < n) ++total_bits;
  const int bits = std::max(1, total_bits / static_cast<int>(d));  // per coordinate
  const std::size_t used = std::min(d, static_cast<std::size_t>(std::max(total_bits, 1)));  // coordinates keyed
  std::vector<double> lo(used, std::numeric_limits<double>::infinity()), scale(used, 0.0);
  std::vector<double> hi(used, -std::numeric_limits<double>::infinity());
  for (std::size_t i = 0; i < n; ++i) {
    for (std::size_t c = 0; c < used; ++c) {
      lo[c] = std::min(lo[c], points.point(i)[c]);
      hi[c] = std::max(hi[c], points.point(i)[c]);
    }
  }
  const double cells = std::ldexp(1.0, bits);
  for (std::size_t c = 0; c < used; ++c) {
    // Halved first: the span of coordinates near the documented range may overflow.
    const double half_span = hi[c] / 2 - lo[c] / 2;
    scale[c] = half_span > 0 ? cells / 2 / half_span : 0.0;
  }
  std::vector<std::uint32_t> code(n);
  for (std::size_t i = 0; i < n; ++i) {
    std::uint32_t z = 0;
    for (std::size_t c = 0; c < used; ++c) {
      const double t = (points.point(i)[c] / 2 - lo[c] / 2) * scale[c];
      const auto cell = static_cast<std::uint32_t>(t >= 0 ? std::min(t, cells - 1) : 0.0);  // NaN: 0 * inf
      for (int b = 0; b < bits; ++b) z |= ((cell >> b) & 1u) << (b * static_cast<int>(used) + static_cast<int>(c));
    }
    code[i] = z;
  }
  const std::size_t buckets = std::size_t{1} << (static_cast<std::size_t>(bits) * used);
  std::vector<std::uint32_t> start(buckets + 1, 0);
  for (std::uint32_t z : code) ++start[z + 1];
  std::partial_sum(start.begin(), start.end(), start.begin());
  std::vector<std::uint32_t> order(n);
  for (std::size_t i = 0; i < n; ++i) order[start[code[i]]++] = static_cast<std::uint32_t>(i);
  return order;
}

}  // namespace

KdTree::KdTree(const PointSet& points)
    : points_(points), adaptor_{nullptr, points.size(), static_cast<std::size_t>(points.dimension())} {
  const std::size_t n = points.size(), d = adaptor_.d;
  // nanoflann builds over a copy in Z-order (see z_order), then reads nothing more.
  // The copy is the tree's own coordinate array, put in leaf order afterwards, so
  // building costs no second copy of the points.
  std::vector<std::uint32_t> order = z_order(points);
  leaf_coords_.resize(n * d);
  // Points are copied coordinate by coordinate: a std::copy_n of a runtime d is a
  // memmove call per point (16% of a 2-d build).
  auto copy_point = [d](const double* from, double* to) {
    for (std::size_t c = 0; c < d; ++c) to[c] = from[c];
  };
  for (std::size_t k = 0; k < n; ++k) copy_point(points.point(order[k]), &leaf_coords_[k * d]);
  adaptor_.coords = leaf_coords_.data();
  index_ = std::make_unique<Index>(points.dimension(), adaptor_,
                                   nanoflann::KDTreeSingleIndexAdaptorParams(/*leaf_max_size=*/8));
  // Now the leaf order: leaf position k holds what was at Z position vAcc[k], and
  // nanoflann's permutation becomes the identity. The same tree, but a query reads
  // each leaf's points from consecutive memory (about 40% of a 3-d 64-NN query's time
  // was reading them from n random places).
  const auto& z_of = index_->vAcc;
  id_of_.resize(n);
  rank_of_.resize(n);
  for (std::size_t k = 0; k < n; ++k) {
    id_of_[k] = order[z_of[k]];
    rank_of_[id_of_[k]] = static_cast<std::uint32_t>(k);
  }
  order = {};
  // In place, cycle by cycle: position k takes Z position z_of[k]'s coordinates.
  std::vector<bool> placed(n, false);
  std::vector<double> saved(d);
  for (std::size_t first = 0; first < n; ++first) {
    if (placed[first]) continue;
    copy_point(&leaf_coords_[first * d], saved.data());
    for (std::size_t k = first;;) {
      placed[k] = true;
      const std::size_t from = z_of[k];
      if (from == first) {
        copy_point(saved.data(), &leaf_coords_[k * d]);
        break;
      }
      copy_point(&leaf_coords_[from * d], &leaf_coords_[k * d]);
      k = from;
    }
  }
  std::iota(index_->vAcc.begin(), index_->vAcc.end(), std::uint32_t{0});
  if (index_->root_node != nullptr) add_box_nodes(index_->root_node);
}

namespace {

// The float nearest to v on the side away from the box's inside (boxes stay
// conservative after rounding). Coordinates reach 1e100, beyond float's range: those
// are clamped before the conversion (a double outside it has no float value).
constexpr double kFloatMax = std::numeric_limits<float>::max();
constexpr float kFloatInf = std::numeric_limits<float>::infinity();
float float_down(double v) {
  if (v > kFloatMax) return std::numeric_limits<float>::max();
  if (v < -kFloatMax) return -kFloatInf;
  const float f = static_cast<float>(v);
  return static_cast<double>(f) > v ? std::nextafter(f, -kFloatInf) : f;
}
float float_up(double v) {
  if (v < -kFloatMax) return -std::numeric_limits<float>::max();
  if (v > kFloatMax) return kFloatInf;
  const float f = static_cast<float>(v);
  return static_cast<double>(f) < v ? std::nextafter(f, kFloatInf) : f;
}

}  // namespace

std::size_t KdTree::add_box_nodes(const Node* node) {
  const std::size_t d = adaptor_.d;
  const std::size_t at = box_nodes_.size();
  box_nodes_.push_back({});
  box_bounds_.resize(box_bounds_.size() + 2 * d);
  BoxNode box{};
  if (node->child1 == nullptr && node->child2 == nullptr) {
    box.begin = static_cast<std::uint32_t>(node->node_type.lr.left);
    box.end = static_cast<std::uint32_t>(node->node_type.lr.right);
    float* lo = &box_bounds_[at * 2 * d];
    float* hi = lo + d;
    for (std::size_t c = 0; c < d; ++c) {
      double low = std::numeric_limits<double>::infinity(), high = -low;  // an empty leaf: an empty box
      for (std::uint32_t k = box.begin; k < box.end; ++k) {
        low = std::min(low, leaf_coords_[k * d + c]);
        high = std::max(high, leaf_coords_[k * d + c]);
      }
      lo[c] = float_down(low);
      hi[c] = float_up(high);
    }
  } else {
    const std::size_t left = add_box_nodes(node->child1);
    const std::size_t right = add_box_nodes(node->child2);
    box.begin = box_nodes_[left].begin;
    box.end = box_nodes_[right].end;
    float* lo = &box_bounds_[at * 2 * d];
    const float* a = &box_bounds_[left * 2 * d];
    const float* b = &box_bounds_[right * 2 * d];
    for (std::size_t c = 0; c < 2 * d; ++c) lo[c] = c < d ? std::min(a[c], b[c]) : std::max(a[c], b[c]);
  }
  box.skip = static_cast<std::uint32_t>(box_nodes_.size());
  box_nodes_[at] = box;
  return at;
}

// nanoflann's searchLevel (1.4.3, eps = 0, L2_Simple_Adaptor) with the dimension a
// compile-time constant. The index is built with a runtime dimension (one type for
// every d), so its own search cannot unroll its distance loops or index the leaf
// copy without a multiplication by d (11% of a 2-d search's instructions, where the
// k-NN search is the largest part of a seed).
// Same tree, same visiting order, same arithmetic in the same order, so the results,
// ties included, are exactly nanoflann's.
template <int D, class ResultSet>
bool KdTree::search_level(const Node* node, ResultSet& result, const double* query, double mindistsq,
                          double* offsets) const {
  if (node->child1 == nullptr && node->child2 == nullptr) {
    const double worst = result.worstDist();  // read once per leaf, as nanoflann does
    for (auto i = node->node_type.lr.left; i < node->node_type.lr.right; ++i) {
      const double* p = &leaf_coords_[i * static_cast<std::size_t>(D)];
      double dist = 0;
      for (int c = 0; c < D; ++c) {
        const double diff = query[c] - p[c];
        dist += diff * diff;
      }
      if (dist < worst && !result.addPoint(dist, static_cast<std::uint32_t>(i))) return false;
    }
    return true;
  }
  const auto feature = node->node_type.sub.divfeat;
  const double value = query[feature];
  const double low = node->node_type.sub.divlow, high = node->node_type.sub.divhigh;
  const bool left_first = (value - low) + (value - high) < 0;
  const Node* near = left_first ? node->child1 : node->child2;
  const Node* far = left_first ? node->child2 : node->child1;
  const double cut = left_first ? (value - high) * (value - high) : (value - low) * (value - low);
  if (!search_level<D>(near, result, query, mindistsq, offsets)) return false;
  const double saved = offsets[feature];
  mindistsq = mindistsq + cut - saved;
  offsets[feature] = cut;
  if (mindistsq <= result.worstDist() && !search_level<D>(far, result, query, mindistsq, offsets)) return false;
  offsets[feature] = saved;
  return true;
}

// nanoflann's findNeighbors, minus its one allocation per query: with a runtime
// dimension it builds a fresh std::vector of per-dimension box offsets each time.
// The same two steps (initial box distances, then the search) run here on a
// per-thread buffer, so the results, ties included, are nanoflann's.
template <class ResultSet>
void KdTree::search(const double* query, ResultSet& result) const {
  if (index_->root_node == nullptr) return;  // no points
  thread_local Index::distance_vector_t offsets;
  offsets.assign(adaptor_.d, 0.0);  // allocates only when a thread first sees this d
  const double distsq = index_->computeInitialDistances(*index_, query, offsets);
  switch (adaptor_.d) {  // the one dispatch from the runtime dimension to compiled searches
    case 2: search_level<2>(index_->root_node, result, query, distsq, offsets.data()); return;
    case 3: search_level<3>(index_->root_node, result, query, distsq, offsets.data()); return;
    case 4: search_level<4>(index_->root_node, result, query, distsq, offsets.data()); return;
    case 5: search_level<5>(index_->root_node, result, query, distsq, offsets.data()); return;
    case 6: search_level<6>(index_->root_node, result, query, distsq, offsets.data()); return;
    case 7: search_level<7>(index_->root_node, result, query, distsq, offsets.data()); return;
    case 8: search_level<8>(index_->root_node, result, query, distsq, offsets.data()); return;
    default: index_->searchLevel(result, query, index_->root_node, distsq, offsets, /*epsError=*/1.0f);
  }
}

std::size_t KdTree::knn(const double* query, std::size_t k, std::uint32_t* ids, double* dist2,
                        const double** coords, double bound2) const {
  nanoflann::KNNResultSet<double, std::uint32_t> result(k);
  result.init(ids, dist2);
  // The set's worst distance starts at "infinity" in its last slot and only falls:
  // starting it at bound2 instead keeps exactly the points closer than bound2.
  if (k != 0 && bound2 < dist2[k - 1]) dist2[k - 1] = bound2;
  search(query, result);
  const std::size_t got = result.size();
  for (std::size_t i = 0; i < got; ++i) {
    if (coords != nullptr) coords[i] = &leaf_coords_[ids[i] * adaptor_.d];
    ids[i] = id_of_[ids[i]];
  }
  return got;
}

void KdTree::within(const double* query, double r2, std::vector<std::pair<std::uint32_t, double>>& out) const {
  nanoflann::RadiusResultSet<double, std::uint32_t> result(r2, out);  // clears out
  search(query, result);
  for (auto& [id, dist2] : out) id = id_of_[id];
}

}  // namespace spokemesh
