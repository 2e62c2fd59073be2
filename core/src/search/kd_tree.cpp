#include "spokemesh/kd_tree.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <system_error>
#include <thread>

#include "base/dimension.hpp"

namespace spokemesh {

namespace {

// The points' order along a Z-order (Morton) curve over a grid of at most 2^20 cells
// spanning their bounding box, by one counting sort. Only a memory layout: nanoflann's
// build partitions the index array over and over, reading each point's coordinates,
// and in this order those reads stay local (bench/README.md, "Tuning history").
// The tree's splits come from the subsets' bounding boxes, whatever their order.
// lo, hi: the points' bounding box (d lows, d highs).
std::vector<std::uint32_t> z_order(const PointSet& points, const double* lo, const double* hi) {
  const std::size_t n = points.size(), d = static_cast<std::size_t>(points.dimension());
  int total_bits = 0;
  while (total_bits < 20 && (std::size_t{1} << total_bits) < n) ++total_bits;
  const int bits = std::max(1, total_bits / static_cast<int>(d));                           // per coordinate
  const std::size_t used = std::min(d, static_cast<std::size_t>(std::max(total_bits, 1)));  // coordinates keyed
  std::vector<double> scale(used, 0.0);
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

// Runs fn(begin, end) over [0, n): in two halves, one on another thread, when
// `parallel` (and a thread is to be had); otherwise as one range here.
template <class Fn>
void in_two_halves(std::size_t n, bool parallel, Fn&& fn) {
  std::thread other;
  if (parallel) {
    try {
      other = std::thread([&] { fn(n / 2, n); });
    } catch (const std::system_error&) {}
  }
  fn(0, other.joinable() ? n / 2 : n);
  if (other.joinable()) other.join();
}

}  // namespace

KdTree::KdTree(const PointSet& points, std::uint32_t first_inexact, double pad)
    : points_(points), d_(static_cast<std::size_t>(points.dimension())), first_inexact_(first_inexact), pad_(pad) {
  build_whole();
}

KdTree::KdTree(const PointSet& points) : points_(points), d_(static_cast<std::size_t>(points.dimension())) {
  build_whole();
}

void KdTree::build_whole() {
  const PointSet& points = points_;
  const std::size_t n = points.size(), d = d_;
  // The bounding box (the Z order's grid, the search's initial distances) and the
  // top split: the widest side, at the median point along it. The two halves are
  // separate nanoflann trees under one root of our own, built concurrently for large
  // sets (nanoflann 1.4.3 builds on one thread; measured in bench/README.md).
  // The split does not depend on the thread count, so neither does the tree.
  bbox_.assign(2 * d, 0.0);
  for (std::size_t c = 0; c < d; ++c) {
    bbox_[c] = std::numeric_limits<double>::infinity();
    bbox_[d + c] = -std::numeric_limits<double>::infinity();
  }
  for (std::size_t i = 0; i < n; ++i) {
    for (std::size_t c = 0; c < d; ++c) {
      bbox_[c] = std::min(bbox_[c], points.point(i)[c]);
      bbox_[d + c] = std::max(bbox_[d + c], points.point(i)[c]);
    }
  }
  // nanoflann builds over a copy in Z-order (see z_order), then reads nothing more;
  // the copy is gathered into leaf order afterwards and becomes the tree's own array.
  std::vector<std::uint32_t> order = z_order(points, bbox_.data(), bbox_.data() + d);
  std::size_t split_dim = 0;
  for (std::size_t c = 1; c < d; ++c) {
    if (bbox_[d + c] - bbox_[c] > bbox_[d + split_dim] - bbox_[split_dim]) split_dim = c;
  }
  std::size_t n_left = n;
  if (n >= kSplitAtLeast && bbox_[d + split_dim] > bbox_[split_dim]) {
    std::vector<double> along(n);
    for (std::size_t i = 0; i < n; ++i) along[i] = points.point(i)[split_dim];
    std::nth_element(along.begin(), along.begin() + static_cast<std::ptrdiff_t>(n / 2), along.end());
    const double median = along[n / 2];
    // Left: below the median; if nothing is (the median is the minimum), at most it.
    // Both sides are non-empty either way, since the side has positive length.
    const bool at_most = median == bbox_[split_dim];
    auto left = [&](std::uint32_t i) {
      const double v = points.point(i)[split_dim];
      return at_most ? v <= median : v < median;
    };
    // Stable: each half keeps the Z order.
    n_left = static_cast<std::size_t>(std::stable_partition(order.begin(), order.end(), left) - order.begin());
  }
  leaf_coords_.resize(n * d);
  // Points are copied coordinate by coordinate: a std::copy_n of a runtime d is a
  // memmove call per point.
  auto copy_point = [d](const double* from, double* to) {
    for (std::size_t c = 0; c < d; ++c) to[c] = from[c];
  };
  const bool parallel = n >= kBuildInParallelAtLeast;
  in_two_halves(n, parallel, [&](std::size_t begin, std::size_t end) {
    for (std::size_t k = begin; k < end; ++k) copy_point(points.point(order[k]), &leaf_coords_[k * d]);
  });
  const std::size_t counts[2] = {n_left, n - n_left};
  const nanoflann::KDTreeSingleIndexAdaptorParams params(/*leaf_max_size=*/8);
  auto built = std::make_shared<Built>();
  Built& b = *built;
  auto build = [&](int h) {
    b.adaptors[h] = Adaptor{leaf_coords_.data() + (h == 0 ? 0 : n_left * d), counts[h], d};
    b.halves[h] = std::make_unique<Index>(static_cast<int>(d), b.adaptors[h], params);
  };
  if (counts[1] == 0) {
    build(0);
  } else {  // the halves on two threads (large sets) or one after the other
    in_two_halves(2, parallel, [&](std::size_t begin, std::size_t end) {
      for (std::size_t h = begin; h < end; ++h) build(static_cast<int>(h));
    });
  }
  // Now the leaf order: leaf position k holds what was at Z position z_of(k) (each
  // half's vAcc, the right half's shifted past the left). The same trees, but a query
  // reads each leaf's points from consecutive memory instead of from n random places.
  auto z_of = [&](std::size_t k) -> std::size_t {
    return k < n_left ? b.halves[0]->vAcc[k] : n_left + b.halves[1]->vAcc[k - n_left];
  };
  id_of_.resize(n);
  rank_of_.resize(n);
  for (std::size_t k = 0; k < n; ++k) {
    id_of_[k] = order[z_of(k)];
    rank_of_[id_of_[k]] = static_cast<std::uint32_t>(k);
  }
  // Gathered into a new array (position k takes Z position z_of(k)'s coordinates):
  // the build briefly holds two copies, but both threads can fill it.
  std::vector<double> gathered(n * d);
  in_two_halves(n, parallel, [&](std::size_t begin, std::size_t end) {
    for (std::size_t k = begin; k < end; ++k) copy_point(&leaf_coords_[z_of(k) * d], &gathered[k * d]);
  });
  leaf_coords_.swap(gathered);
  gathered = {};
  order = {};
  // Leaves name ranges of leaf positions: the right half's start past the left's.
  // (nanoflann's own searches, which would read vAcc, are never used.)
  const Node* root = b.halves[0]->root_node;
  if (counts[1] != 0) {
    shift_leaves(b.halves[1]->root_node, static_cast<std::uint32_t>(n_left));
    b.top.node_type.sub.divfeat = static_cast<int>(split_dim);
    double left_high = -std::numeric_limits<double>::infinity(), right_low = -left_high;
    for (std::size_t k = 0; k < n; ++k) {
      const double v = leaf_coords_[k * d + split_dim];
      if (k < n_left) {
        left_high = std::max(left_high, v);
      } else {
        right_low = std::min(right_low, v);
      }
    }
    b.top.node_type.sub.divlow = left_high;   // as nanoflann: the left box's high side
    b.top.node_type.sub.divhigh = right_low;  // and the right box's low side
    b.top.child1 = b.halves[0]->root_node;
    b.top.child2 = b.halves[1]->root_node;
    root = &b.top;
  }
  if (root != nullptr) {
    add_box_nodes(root);
    parts_.push_back({root, bbox_});
  }
  built_.push_back(std::move(built));
}

KdTree::KdTree(const KdTree& base, const PointSet& points)
    : points_(points), d_(static_cast<std::size_t>(points.dimension())) {
  const std::size_t d = d_, n_old = base.points().size(), n = points.size();
  // The new points' own tree, whose nodes become the last part (leaf positions
  // shifted past the base's) and whose arrays are appended to copies of the base's.
  const PointSet more(static_cast<int>(d),
                      std::vector<double>(points.coordinates().begin() + static_cast<std::ptrdiff_t>(n_old * d),
                                          points.coordinates().end()));
  KdTree extra(more);
  for (const std::shared_ptr<Built>& b : extra.built_) {
    if (b->halves[0] != nullptr) shift_leaves(b->halves[0]->root_node, static_cast<std::uint32_t>(n_old));
    if (b->halves[1] != nullptr) shift_leaves(b->halves[1]->root_node, static_cast<std::uint32_t>(n_old));
  }
  built_ = base.built_;
  built_.insert(built_.end(), extra.built_.begin(), extra.built_.end());
  parts_ = base.parts_;
  parts_.insert(parts_.end(), extra.parts_.begin(), extra.parts_.end());
  bbox_ = base.bbox_;
  for (std::size_t c = 0; c < d && !extra.bbox_.empty(); ++c) {
    bbox_[c] = std::min(bbox_[c], extra.bbox_[c]);
    bbox_[d + c] = std::max(bbox_[d + c], extra.bbox_[d + c]);
  }
  leaf_coords_.reserve(n * d);
  leaf_coords_ = base.leaf_coords_;
  leaf_coords_.insert(leaf_coords_.end(), extra.leaf_coords_.begin(), extra.leaf_coords_.end());
  id_of_.reserve(n);
  id_of_ = base.id_of_;
  rank_of_.reserve(n);
  rank_of_ = base.rank_of_;
  for (std::size_t k = 0; k < n - n_old; ++k) {
    id_of_.push_back(static_cast<std::uint32_t>(n_old) + extra.id_of_[k]);
    rank_of_.push_back(static_cast<std::uint32_t>(n_old) + extra.rank_of_[k]);
  }
  // The box trees one after the other: find_first's preorder walk reads them as two
  // consecutive subtrees (positions and skips shifted past the base's).
  box_nodes_ = base.box_nodes_;
  const auto nodes_before = static_cast<std::uint32_t>(box_nodes_.size());
  for (BoxNode node : extra.box_nodes_) {
    node.begin += static_cast<std::uint32_t>(n_old);
    node.end += static_cast<std::uint32_t>(n_old);
    node.skip += nodes_before;
    box_nodes_.push_back(node);
  }
  box_bounds_ = base.box_bounds_;
  box_bounds_.insert(box_bounds_.end(), extra.box_bounds_.begin(), extra.box_bounds_.end());
}

std::unique_ptr<KdTree> KdTree::extended(const KdTree& base, const PointSet& points) {
  const std::size_t n_old = base.points().size(), n = points.size();
  // Each part costs every search a descent from its root; past a few, or once the
  // added points are a large share (their tree would be most of a rebuild's cost
  // anyway), the whole tree is built again.
  if (base.parts_.size() >= kMaxParts || n <= n_old || (n - n_old) * kRebuildBeyondShare > n) {
    return std::make_unique<KdTree>(points);
  }
  return std::unique_ptr<KdTree>(new KdTree(base, points));
}

void KdTree::shift_leaves(Node* node, std::uint32_t by) {
  if (node == nullptr) return;
  if (node->child1 == nullptr && node->child2 == nullptr) {
    node->node_type.lr.left += by;
    node->node_type.lr.right += by;
    return;
  }
  shift_leaves(node->child1, by);
  shift_leaves(node->child2, by);
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
  const std::size_t d = d_;
  const std::size_t at = box_nodes_.size();
  box_nodes_.push_back({});
  box_bounds_.resize(box_bounds_.size() + 2 * d);
  BoxNode box{};
  if (node->child1 == nullptr && node->child2 == nullptr) {
    box.begin = static_cast<std::uint32_t>(node->node_type.lr.left);
    box.end = static_cast<std::uint32_t>(node->node_type.lr.right);
    float* lo = &box_bounds_[at * 2 * d];
    float* hi = lo + d;
    bool inexact = false;
    for (std::uint32_t k = box.begin; k < box.end; ++k) inexact |= id_of_[k] >= first_inexact_;
    for (std::size_t c = 0; c < d; ++c) {
      double low = std::numeric_limits<double>::infinity(), high = -low;  // an empty leaf: an empty box
      for (std::uint32_t k = box.begin; k < box.end; ++k) {
        low = std::min(low, leaf_coords_[k * d + c]);
        high = std::max(high, leaf_coords_[k * d + c]);
      }
      if (inexact && box.begin < box.end) {
        lo[c] = float_down(low - pad_);
        hi[c] = float_up(high + pad_);
        continue;
      }
      lo[c] = float_down(low);
      hi[c] = float_up(high);
      if (low == high) box.flat |= 1u << c;
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
    // Flat where both children are, at the same value.
    const double* first_left = leaf_coords_.data() + std::size_t{box_nodes_[left].begin} * d;
    const double* first_right = leaf_coords_.data() + std::size_t{box_nodes_[right].begin} * d;
    for (std::size_t c = 0; c < d; ++c) {
      if ((box_nodes_[left].flat & box_nodes_[right].flat & (1u << c)) != 0 && first_left[c] == first_right[c]) {
        box.flat |= 1u << c;
      }
    }
  }
  box.skip = static_cast<std::uint32_t>(box_nodes_.size());
  box_nodes_[at] = box;
  return at;
}

std::vector<KdTree::Subtree> KdTree::subtrees_of_at_most(std::uint32_t max_points) const {
  // Preorder over the box tree: a small enough subtree is taken whole and skipped.
  std::vector<Subtree> out;
  for (std::size_t i = 0; i < box_nodes_.size();) {
    const BoxNode& node = box_nodes_[i];
    const bool leaf = node.skip == i + 1;
    if (leaf || node.end - node.begin <= max_points) {
      out.push_back({node.begin, node.end, &box_bounds_[i * 2 * d_]});
      i = node.skip;
    } else {
      ++i;
    }
  }
  return out;
}

// nanoflann's searchLevel (1.4.3, eps = 0, L2_Simple_Adaptor), with the dimension a
// compile-time constant for d <= 8 (D = 0: the runtime d). The index is built with a
// runtime dimension (one type for every d), so its own search cannot unroll its
// distance loops or index the leaf copy without a multiplication by d (a 2-d k-NN
// search, the largest part of a 2-d seed, spent a tenth of its instructions there); and
// ours reads the leaf-ordered copy, which spans both halves of the tree.
// Same visiting order, same arithmetic in the same order as nanoflann's.
// Guarded by the version: another nanoflann may visit or round differently (the
// brute-force tests of test_kd_tree.cpp check the answers, not the equivalence).
// Debian's 1.4.3 still reports 0x142: upstream did not bump the macro in that release.
static_assert(NANOFLANN_VERSION == 0x142,
              "search_level mirrors nanoflann 1.4.3's searchLevel (whose header says 0x142): compare it "
              "with this version's and update the check");
template <int D, class ResultSet>
bool KdTree::search_level(const Node* node, ResultSet& result, const double* query, double mindistsq,
                          double* offsets) const {
  const std::size_t dim = D > 0 ? static_cast<std::size_t>(D) : d_;
  if (node->child1 == nullptr && node->child2 == nullptr) {
    const double worst = result.worstDist();  // read once per leaf, as nanoflann does
    for (auto i = node->node_type.lr.left; i < node->node_type.lr.right; ++i) {
      const double* p = &leaf_coords_[i * dim];
      double dist = 0;
      for (std::size_t c = 0; c < dim; ++c) {
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

// nanoflann's findNeighbors (initial box distances, then the search), minus its one
// allocation per query: with a runtime dimension it builds a fresh std::vector of
// per-dimension box offsets each time; here they live in a per-thread buffer.
// An extended tree's parts are searched one after another into the same result set
// (a part whose box lies beyond the worst distance so far is skipped).
template <class ResultSet>
void KdTree::search(const double* query, ResultSet& result) const {
  thread_local std::vector<double> offsets;
  for (const Part& part : parts_) {
    const double* bbox = part.bbox.data();
    offsets.assign(d_, 0.0);  // allocates only when a thread first sees this d
    double distsq = 0;
    for (std::size_t c = 0; c < d_; ++c) {  // as nanoflann's computeInitialDistances
      if (query[c] < bbox[c]) {
        offsets[c] = (query[c] - bbox[c]) * (query[c] - bbox[c]);
        distsq += offsets[c];
      }
      if (query[c] > bbox[d_ + c]) {
        offsets[c] = (query[c] - bbox[d_ + c]) * (query[c] - bbox[d_ + c]);
        distsq += offsets[c];
      }
    }
    if (distsq > result.worstDist()) continue;
    detail::dispatch_dimension(static_cast<int>(d_), [&](auto dim) {
      search_level<decltype(dim)::value>(part.root, result, query, distsq, offsets.data());
    });
  }
}

std::size_t KdTree::knn(const double* query, std::size_t k, std::uint32_t* ids, double* dist2, const double** coords,
                        double bound2) const {
  nanoflann::KNNResultSet<double, std::uint32_t> result(k);
  result.init(ids, dist2);
  // The set's worst distance starts at "infinity" in its last slot and only falls:
  // starting it at bound2 instead keeps exactly the points closer than bound2.
  if (k != 0 && bound2 < dist2[k - 1]) dist2[k - 1] = bound2;
  search(query, result);
  const std::size_t got = result.size();
  for (std::size_t i = 0; i < got; ++i) {
    if (coords != nullptr) coords[i] = &leaf_coords_[ids[i] * d_];
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
