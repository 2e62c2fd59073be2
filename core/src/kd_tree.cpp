#include "spokemesh/kd_tree.hpp"

namespace spokemesh {

KdTree::KdTree(const PointSet& points) : adaptor_{points} {
  index_ = std::make_unique<Index>(points.dimension(), adaptor_,
                                   nanoflann::KDTreeSingleIndexAdaptorParams(/*leaf_max_size=*/8));
}

std::size_t KdTree::knn(const double* query, std::size_t k, std::uint32_t* ids, double* dist2) const {
  return index_->knnSearch(query, k, ids, dist2);
}

void KdTree::within(const double* query, double r2, std::vector<std::pair<std::uint32_t, double>>& out) const {
  out.clear();
  index_->radiusSearch(query, r2, out, nanoflann::SearchParams(32, 0, /*sorted=*/false));
}

}  // namespace spokemesh
