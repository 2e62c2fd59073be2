// libFuzzer target: the point-file readers (text and CSV share parse_text_points;
// .npy has parse_npy_points) and the weight-file readers on the same bytes. Any input
// must give a PointSet (weights) or one clear error, never a crash, a hang or undefined
// behaviour (built with ASan and UBSan). A small valid set is then meshed with weights
// read from its own coordinates (the regular triangulation's start and hidden seeds).
// SPOKEMESH_FUZZ_NPY selects the reader at compile time (tests/fuzz/CMakeLists.txt).
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "spokemesh/io.hpp"
#include "spokemesh/kd_tree.hpp"
#include "spokemesh/star.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string bytes(reinterpret_cast<const char*>(data), size);
#ifdef SPOKEMESH_FUZZ_NPY
  auto points = spokemesh::parse_npy_points(bytes, "fuzz.npy");
#else
  auto points = spokemesh::parse_text_points(bytes, "fuzz.txt");
#endif
  for (const auto kind : {spokemesh::WeightKind::kPowerWeight, spokemesh::WeightKind::kRadius}) {
#ifdef SPOKEMESH_FUZZ_NPY
    auto weights = spokemesh::parse_npy_weights(bytes, "fuzz.npy", 4, kind);
#else
    auto weights = spokemesh::parse_text_weights(bytes, "fuzz.txt", 4, kind);
#endif
    if (!weights.is_ok() && weights.status().message().empty()) __builtin_trap();
  }
  if (points.is_ok()) {
    spokemesh::PointSet ps = std::move(points).value();
    // what every reader's caller does next
    if (ps.validate("fuzz").is_ok() && ps.size() <= 64 && ps.dimension() <= 4) {
      std::vector<double> w(ps.size());
      for (std::size_t i = 0; i < ps.size(); ++i) w[i] = ps.point(static_cast<std::uint32_t>(i))[0];
      auto checked = spokemesh::weights_from_values(w, "fuzz", ps.size(), spokemesh::WeightKind::kPowerWeight);
      if (checked.is_ok()) {
        const spokemesh::KdTree tree(ps);
        spokemesh::StarOptions options;
        options.weights = checked.value();
        spokemesh::StarWalker walker(tree, options);
        spokemesh::Star star;
        for (std::uint32_t s = 0; s < ps.size(); ++s) (void)walker.compute(s, star);
      }
    }
  } else if (points.status().message().empty()) {
    __builtin_trap();  // an error must say what and where
  }
  return 0;
}
