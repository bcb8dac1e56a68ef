// CGAL's whole process, for the whole-process comparison with `geomfit curvature --local`
// (bench/README.md, issue 15): read an OBJ with CGAL::IO::read_OBJ, build a
// CGAL::Surface_mesh, gather each vertex's k-ring stencil (k = ceil((d + 1) / 2), breadth
// first over the mesh's halfedges, vertex first), fit CGAL::Monge_via_jet_fitting
// (d_fitting = d, d_monge = 2), orient the Monge normal like the area-weighted vertex
// normal, and write normal, k1, k2 per vertex as raw float64 (N x 5).
//
//   cgal_whole_process MESH.obj DEGREE OUT.bin
#include <cmath>
#include <cstdio>
#include <fstream>
#include <vector>

#include <CGAL/IO/OBJ.h>
#include <CGAL/Monge_via_jet_fitting.h>
#include <CGAL/Polygon_mesh_processing/compute_normal.h>
#include <CGAL/Polygon_mesh_processing/polygon_soup_to_polygon_mesh.h>
#include <CGAL/Simple_cartesian.h>
#include <CGAL/Surface_mesh.h>

using Kernel = CGAL::Simple_cartesian<double>;
using Point = Kernel::Point_3;
using Mesh = CGAL::Surface_mesh<Point>;
using Vertex = Mesh::Vertex_index;
using MongeVia = CGAL::Monge_via_jet_fitting<Kernel>;
namespace PMP = CGAL::Polygon_mesh_processing;

int main(int argc, char** argv) {
  if (argc != 4) {
    std::fprintf(stderr, "usage: cgal_whole_process MESH.obj DEGREE OUT.bin\n");
    return 2;
  }
  const int degree = std::atoi(argv[2]);
  std::vector<Point> points;
  std::vector<std::vector<std::size_t>> polygons;
  if (!CGAL::IO::read_OBJ(argv[1], points, polygons)) {
    std::fprintf(stderr, "cannot read %s\n", argv[1]);
    return 1;
  }
  Mesh mesh;
  PMP::polygon_soup_to_polygon_mesh(points, polygons, mesh);
  auto normals = mesh.add_property_map<Vertex, Kernel::Vector_3>("v:normal").first;
  PMP::compute_vertex_normals(mesh, normals);

  const int rings = (degree + 2) / 2;
  const std::size_t nv = mesh.number_of_vertices();
  std::vector<int> mark(nv, -1);
  std::vector<Vertex> stencil, next;
  std::vector<Point> pts;
  std::vector<double> out(nv * 5);
  MongeVia fitter;
  std::size_t total = 0;
  for (Vertex v : mesh.vertices()) {
    stencil.assign(1, v);
    mark[v] = static_cast<int>(v);
    std::size_t begin = 0;
    for (int r = 0; r < rings; ++r) {
      const std::size_t end = stencil.size();
      for (std::size_t i = begin; i < end; ++i)
        for (Vertex w : CGAL::vertices_around_target(mesh.halfedge(stencil[i]), mesh))
          if (mark[w] != static_cast<int>(v)) mark[w] = static_cast<int>(v), stencil.push_back(w);
      begin = end;
    }
    pts.clear();
    for (Vertex w : stencil) pts.push_back(mesh.point(w));
    total += pts.size();
    MongeVia::Monge_form m = fitter(pts.begin(), pts.end(), degree, 2);
    m.comply_wrt_given_normal(normals[v]);
    const auto n = m.normal_direction();
    double* o = out.data() + 5 * static_cast<std::size_t>(v);
    o[0] = n.x(), o[1] = n.y(), o[2] = n.z();
    o[3] = m.principal_curvatures(0), o[4] = m.principal_curvatures(1);
  }
  std::ofstream f(argv[3], std::ios::binary);
  f.write(reinterpret_cast<const char*>(out.data()), out.size() * sizeof(double));
  std::fprintf(stderr, "%zu vertices, mean stencil %.1f points (%d rings)\n", nv, double(total) / nv, rings);
  return f ? 0 : 1;
}
