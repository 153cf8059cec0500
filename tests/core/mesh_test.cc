#include "core/mesh.h"

#include <cstring>
#include <fstream>

#include <gtest/gtest.h>

#include "core/error.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

// A closed unit-ish tetrahedron with outward normals.
TriangleMesh Tetrahedron() {
  TriangleMesh m;
  m.vertices = {{0, 0, 0}, {10, 0, 0}, {0, 10, 0}, {0, 0, 10}};
  m.triangles = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
  return m;
}

void ExpectSameMesh(const TriangleMesh& a, const TriangleMesh& b) {
  ASSERT_EQ(a.vertices.size(), b.vertices.size());
  ASSERT_EQ(a.triangles.size(), b.triangles.size());
  for (size_t i = 0; i < a.triangles.size(); ++i) {
    for (int k = 0; k < 3; ++k) {
      EXPECT_EQ(a.vertices[a.triangles[i][k]], b.vertices[b.triangles[i][k]]);
    }
  }
}

TEST(Mesh, AreaNormalsAndManifold) {
  const TriangleMesh m = Tetrahedron();
  EXPECT_NEAR(m.SurfaceArea(), 3 * 50 + 0.5 * std::sqrt(3.0) * 200 / 2 * 1.0, 1e-9);
  EXPECT_EQ(m.FaceNormal(0), Eigen::Vector3d(0, 0, -1));
  EXPECT_EQ(m.CountNonManifoldEdges(), 0u);
  TriangleMesh fin = m;
  fin.vertices.push_back({-5, -5, 0});
  fin.triangles.push_back({0, 1, 4});  // a third triangle on edge 0-1
  EXPECT_EQ(fin.CountNonManifoldEdges(), 1u);
}

TEST(Mesh, PlyAndStlRoundTrip) {
  testing::TempDir dir;
  const TriangleMesh m = Tetrahedron();
  WriteMesh(dir / "t.ply", m);
  ExpectSameMesh(m, ReadMesh(dir / "t.ply"));
  WriteMesh(dir / "t.stl", m);  // float precision; these coordinates are exact in float
  ExpectSameMesh(m, ReadMesh(dir / "t.stl"));
}

TEST(Mesh, ReadsAsciiStlAndObjWithPolygons) {
  testing::TempDir dir;
  {
    std::ofstream f(dir / "a.stl");
    f << "solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 "
         "0\nendloop\nendfacet\n"
         "facet normal 0 0 1\nouter loop\nvertex 1 0 0\nvertex 1 1 0\nvertex 0 1 "
         "0\nendloop\nendfacet\nendsolid x\n";
  }
  const TriangleMesh stl = ReadMesh(dir / "a.stl");
  EXPECT_EQ(stl.vertices.size(), 4u);  // shared corners merged
  EXPECT_EQ(stl.triangles.size(), 2u);
  {
    std::ofstream f(dir / "q.obj");
    f << "# quad\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//1 4//1\nf -4 -3 "
         "-2\n";
  }
  const TriangleMesh obj = ReadMesh(dir / "q.obj");
  EXPECT_EQ(obj.triangles.size(), 3u);
  EXPECT_NEAR(obj.TriangleArea(0) + obj.TriangleArea(1), 1.0, 1e-12);
}

TEST(Mesh, BadInputGivesClearErrors) {
  testing::TempDir dir;
  EXPECT_THROW(ReadMesh(dir / "missing.stl"), Error);
  {
    std::ofstream f(dir / "bad.obj");
    f << "v 0 0 0\nf 1 2 3\n";
  }
  try {
    ReadMesh(dir / "bad.obj");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("line 2"), std::string::npos) << e.what();
  }
  {
    std::ofstream f(dir / "empty.obj");
    f << "v 0 0 0\n";
  }
  EXPECT_THROW(ReadMesh(dir / "empty.obj"), Error);
  {
    std::ofstream f(dir / "x.off");
    f << "OFF\n";
  }
  EXPECT_THROW(ReadMesh(dir / "x.off"), Error);
  TriangleMesh degenerate = Tetrahedron();
  degenerate.triangles.push_back({0, 1, 1});
  EXPECT_THROW(degenerate.Check("part.stl"), Error);
  TriangleMesh nan = Tetrahedron();
  nan.vertices[2].x() = std::nan("");
  EXPECT_THROW(nan.Check("part.stl"), Error);
}

// Check runs over the triangles in parallel and still names the first bad one, as a serial loop
// would: a large grid with a degenerate and a dangling triangle far apart.
TEST(Mesh, CheckNamesTheFirstBadTriangle) {
  TriangleMesh grid;
  const int n = 400;
  for (int y = 0; y <= n; ++y) {
    for (int x = 0; x <= n; ++x) grid.vertices.emplace_back(x, y, 0.01 * ((x * 7 + y * 3) % 5));
  }
  for (int y = 0; y < n; ++y) {
    for (int x = 0; x < n; ++x) {
      const int a = y * (n + 1) + x;
      grid.triangles.emplace_back(a, a + 1, a + n + 1);
      grid.triangles.emplace_back(a + 1, a + n + 2, a + n + 1);
    }
  }
  EXPECT_NO_THROW(grid.Check("grid.ply"));
  const auto message = [&](const TriangleMesh& m) {
    try {
      m.Check("grid.ply");
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  TriangleMesh bad = grid;
  bad.triangles[250001] = Eigen::Vector3i(5, 6, 5);
  bad.triangles[318000] = Eigen::Vector3i(5, 6, 1 << 30);
  EXPECT_NE(message(bad).find("grid.ply: triangle 250001 is degenerate"), std::string::npos)
      << message(bad);
  bad.triangles[17] = Eigen::Vector3i(5, 6, -1);
  EXPECT_NE(message(bad).find("grid.ply: triangle 17 refers to vertex -1"), std::string::npos)
      << message(bad);
  TriangleMesh only_degenerate = grid;
  only_degenerate.triangles[250001] = Eigen::Vector3i(5, 6, 5);
  EXPECT_NO_THROW(only_degenerate.Check("grid.ply", /*reject_degenerate=*/false));
}

// A face count in a PLY mesh header is bounded by the data before allocation; a binary STL whose
// triangle count disagrees with its size is not read as binary.
TEST(Mesh, HugeHeaderCountsAreRefusedBeforeAllocation) {
  testing::TempDir dir;
  const std::string ply = (dir / "huge_faces.ply").string();
  std::ofstream(ply, std::ios::binary)
      << "ply\nformat binary_little_endian 1.0\nelement vertex 3\n"
         "property float x\nproperty float y\nproperty float z\n"
         "element face 1000000000000\nproperty list uchar int vertex_indices\n"
         "end_header\n"
      << std::string(36 + 13, '\0');
  try {
    ReadMesh(ply);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(std::string(e.what()),
              ply +
                  ": PLY header: element 'face' claims 1000000000000 rows, but the file has "
                  "only 49 bytes of data (at least 1 bytes per row)");
  }
  const std::string stl = (dir / "huge.stl").string();
  std::string bytes(84, '\0');
  const uint32_t count = 0xFFFFFFFFu;
  std::memcpy(bytes.data() + 80, &count, 4);
  std::ofstream(stl, std::ios::binary) << bytes;
  try {
    ReadMesh(stl);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(
                  stl + ": not an STL file (binary size does not match its triangle count"),
              std::string::npos)
        << e.what();
  }
}

}  // namespace
}  // namespace slshadow
