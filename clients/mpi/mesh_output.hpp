// spokemesh-mpi's .vtu, .msh and .svg meshes: the CLI's file (MeshFileLayout, io.hpp)
// written section by section, each rank its slice of the points and its part of the
// rows, at offsets from every rank's sizes.
//
// Thread safety: collective (main thread).
#pragma once

#include <cstdint>
#include <functional>
#include <span>
#include <string>

#include "comm.hpp"
#include "spokemesh/io.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh::mpi {

// Calls its argument for each of the rank's rows, in order (global indices).
using RowVisitor = std::function<void(const std::function<void(std::span<const std::uint32_t>)>&)>;

// slice_coords: the coordinates of this rank's slice of the index range (slice_begin);
// box: the whole set's (d lows, d highs); point(v): the coordinates of a row's vertex v
// (a point this rank holds). Collective.
Status write_mesh_sections(Comm& comm, const std::string& path, MeshWriter::Format format, int d, std::uint64_t n,
                           std::span<const double> box, std::span<const double> slice_coords, std::uint64_t my_rows,
                           const RowVisitor& for_each_row, const std::function<const double*(std::uint32_t)>& point);

}  // namespace spokemesh::mpi
