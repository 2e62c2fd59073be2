// libFuzzer target: the point-file readers (text and CSV share parse_text_points;
// .npy has parse_npy_points). Any input must give a PointSet or one clear error,
// never a crash, a hang or undefined behaviour (built with ASan and UBSan).
// SPOKEMESH_FUZZ_NPY selects the reader at compile time (tests/fuzz/CMakeLists.txt).
#include <cstddef>
#include <cstdint>
#include <string>

#include "spokemesh/io.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string bytes(reinterpret_cast<const char*>(data), size);
#ifdef SPOKEMESH_FUZZ_NPY
  auto points = spokemesh::parse_npy_points(bytes, "fuzz.npy");
#else
  auto points = spokemesh::parse_text_points(bytes, "fuzz.txt");
#endif
  if (points.is_ok()) {
    spokemesh::PointSet ps = std::move(points).value();
    (void)ps.validate("fuzz");  // what every reader's caller does next
  } else if (points.status().message().empty()) {
    __builtin_trap();  // an error must say what and where
  }
  return 0;
}
