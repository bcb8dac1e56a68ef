// Every RPC with bad input: the status code and message are right, the server stays
// healthy, and the stored reference mesh is intact afterwards.
#include <functional>

#include <gtest/gtest.h>

#include "proto/wire.h"
#include "tests/server/test_util.h"

namespace geomfit::server {
namespace {

using testing::InProcessServer;
using Code = grpc::StatusCode;

struct Case {
  std::string name;
  std::function<grpc::Status(v1::GeomFit::Stub&)> call;
  Code code;
  std::string message;  ///< substring the error message must contain
};

class BadInputTest : public ::testing::Test {
 protected:
  static ServerOptions Options() {
    ServerOptions o = testing::LoopbackOptions();
    o.max_message_bytes = 1 << 20;
    o.max_vertices = 5000;
    return o;
  }

  void SetUp() override {
    mesh_ = testing::TestTorus(10);
    auto info = testing::UploadMesh(server_.stub(), mesh_, "reference");
    ASSERT_TRUE(info.ok()) << info.status();
    id_ = info->mesh_id();
  }

  std::vector<v1::UploadMeshRequest> Chunks() const { return wire::UploadChunks(mesh_, v1::MeshHeader(), 100); }
  std::vector<v1::UploadMeshRequest> Mutated(std::function<void(Mesh&)> f) const {
    Mesh m = mesh_;
    f(m);
    v1::MeshHeader h;
    h.set_name("mutated");
    return wire::UploadChunks(m, h, 100);
  }
  grpc::Status Upload(v1::GeomFit::Stub& stub, const std::vector<v1::UploadMeshRequest>& r) {
    v1::MeshInfo info;
    return testing::SendUpload(stub, r, &info);
  }
  grpc::Status Update(v1::GeomFit::Stub& stub, const Positions& p, std::optional<int64_t> expected,
                      const std::string& id) {
    v1::UpdateHeader h;
    h.set_mesh_id(id);
    if (expected) h.set_expected_revision(*expected);
    v1::MeshInfo info;
    return testing::SendUpdate(stub, wire::UpdateChunks(p, h, 100), &info);
  }
  grpc::Status ComputeWith(v1::GeomFit::Stub& stub, std::function<void(v1::ComputeDifferentialsRequest&)> f) {
    v1::ComputeDifferentialsRequest r;
    r.set_mesh_id(id_);
    f(r);
    std::vector<v1::ComputeDifferentialsResponse> chunks;
    return testing::Compute(stub, r, &chunks);
  }

  void Run(const std::vector<Case>& cases) {
    for (const Case& c : cases) {
      SCOPED_TRACE(c.name);
      const grpc::Status s = c.call(server_.stub());
      EXPECT_EQ(s.error_code(), c.code) << s.error_message();
      EXPECT_NE(s.error_message().find(c.message), std::string::npos)
          << "message '" << s.error_message() << "' lacks '" << c.message << "'";
      EXPECT_EQ(testing::HealthCheck(server_.channel()), "SERVING");
      auto m = testing::Download(server_.stub(), id_);
      ASSERT_TRUE(m.ok()) << m.status();
      EXPECT_TRUE(testing::SameMesh(*m, mesh_)) << "the reference mesh changed";
    }
    grpc::ClientContext ctx;
    v1::GetMeshRequest get;
    get.set_mesh_id(id_);
    v1::MeshInfo info;
    ASSERT_TRUE(server_.stub().GetMesh(&ctx, get, &info).ok());
    EXPECT_EQ(info.revision(), 1);
  }

  InProcessServer server_{Options()};
  Mesh mesh_;
  std::string id_;
};

TEST_F(BadInputTest, UploadMesh) {
  Run({
      {"positions before header",
       [&](auto& s) { auto r = Chunks(); std::swap(r[0], r[1]); return Upload(s, r); },
       Code::INVALID_ARGUMENT, "before the header"},
      {"header twice", [&](auto& s) { auto r = Chunks(); r.insert(r.begin(), r[0]); return Upload(s, r); },
       Code::INVALID_ARGUMENT, "sent twice"},
      {"wrong byte length",
       [&](auto& s) { auto r = Chunks(); r[1].mutable_positions()->mutable_positions()->mutable_data()->pop_back(); return Upload(s, r); },
       Code::INVALID_ARGUMENT, "bytes"},
      {"5 columns",
       [&](auto& s) { auto r = Chunks(); r[1].mutable_positions()->mutable_positions()->set_shape(1, 5); return Upload(s, r); },
       Code::INVALID_ARGUMENT, "shape[1] is 5"},
      {"3-d shape",
       [&](auto& s) { auto r = Chunks(); r[1].mutable_positions()->mutable_positions()->add_shape(1); return Upload(s, r); },
       Code::INVALID_ARGUMENT, "3 dimensions"},
      {"face index out of range", [&](auto& s) { return Upload(s, Mutated([](Mesh& m) { m.faces.Mutable()(7, 1) = 100000; })); },
       Code::INVALID_ARGUMENT, "face 7"},
      {"negative face index", [&](auto& s) { return Upload(s, Mutated([](Mesh& m) { m.faces.Mutable()(3, 0) = -5; })); },
       Code::INVALID_ARGUMENT, "face 3"},
      {"NaN position", [&](auto& s) { return Upload(s, Mutated([](Mesh& m) { m.positions(12, 2) = std::nan(""); })); },
       Code::INVALID_ARGUMENT, "vertex 12"},
      {"flipped face", [&](auto& s) { return Upload(s, Mutated([](Mesh& m) { std::swap(m.faces.Mutable()(4, 0), m.faces.Mutable()(4, 1)); })); },
       Code::INVALID_ARGUMENT, "orientation"},
      {"truncated stream", [&](auto& s) { auto r = Chunks(); r.pop_back(); return Upload(s, r); },
       Code::INVALID_ARGUMENT, "ended after"},
      {"chunk out of order", [&](auto& s) { auto r = Chunks(); std::swap(r[1], r[2]); return Upload(s, r); },
       Code::INVALID_ARGUMENT, "vertex_offset is 100, expected 0"},
      {"empty chunk", [&](auto& s) { auto r = Chunks(); r.insert(r.begin() + 1, v1::UploadMeshRequest()); return Upload(s, r); },
       Code::INVALID_ARGUMENT, "empty chunk"},
      {"empty stream", [&](auto& s) { return Upload(s, {}); }, Code::INVALID_ARGUMENT, "without a header"},
      {"face kind mismatch",
       [&](auto& s) { auto r = Chunks(); r[0].mutable_header()->set_face_kind(v1::FACE_KIND_QUAD); return Upload(s, r); },
       Code::INVALID_ARGUMENT, "face_kind"},
      {"too many vertices",
       [&](auto& s) { auto r = Chunks(); r[0].mutable_header()->set_num_vertices(6000); return Upload(s, r); },
       Code::RESOURCE_EXHAUSTED, "--max-vertices"},
      {"oversized message",
       [&](auto& s) {
         auto r = Chunks();
         r[1].mutable_positions()->mutable_positions()->mutable_data()->assign(2 << 20, 'x');
         return Upload(s, r);
       },
       Code::RESOURCE_EXHAUSTED, ""},
  });
}

TEST_F(BadInputTest, UpdatePositions) {
  Positions nan = mesh_.positions;
  nan(3, 0) = std::numeric_limits<double>::infinity();
  Run({
      {"unknown mesh", [&](auto& s) { return Update(s, mesh_.positions, std::nullopt, "m-nope"); }, Code::NOT_FOUND,
       "m-nope"},
      {"stale revision", [&](auto& s) { return Update(s, mesh_.positions * 2.0, 7, id_); }, Code::ABORTED,
       "expected_revision 7"},
      {"too few vertices", [&](auto& s) { return Update(s, mesh_.positions.topRows(10), std::nullopt, id_); },
       Code::INVALID_ARGUMENT, "carried 10 vertices"},
      {"infinite coordinate", [&](auto& s) { return Update(s, nan, std::nullopt, id_); }, Code::INVALID_ARGUMENT,
       "vertex 3"},
      {"no header",
       [&](auto& s) {
         v1::UpdatePositionsRequest r;
         r.mutable_positions()->set_vertex_offset(0);
         v1::MeshInfo info;
         return testing::SendUpdate(s, {r}, &info);
       },
       Code::INVALID_ARGUMENT, "before the header"},
      {"cancelled mid-stream",
       [&](auto& s) {
         grpc::ClientContext ctx;
         v1::MeshInfo info;
         auto writer = s.UpdatePositions(&ctx, &info);
         v1::UpdateHeader h;
         h.set_mesh_id(id_);
         auto chunks = wire::UpdateChunks(mesh_.positions * 2.0, h, 100);
         writer->Write(chunks[0]);
         writer->Write(chunks[1]);
         ctx.TryCancel();
         return writer->Finish();
       },
       Code::CANCELLED, ""},
  });
}

TEST_F(BadInputTest, SetPositions) {
  auto set = [](const Positions& p, std::optional<int64_t> expected, const std::string& id,
                 std::function<void(v1::SetPositionsRequest&)> edit = nullptr) {
    return [=](v1::GeomFit::Stub& s) {
      v1::SetPositionsRequest r;
      r.mutable_header()->set_mesh_id(id);
      if (expected) r.mutable_header()->set_expected_revision(*expected);
      wire::EncodeDoubles(p.data(), p.rows(), 3, r.mutable_positions()->mutable_positions());
      if (edit) edit(r);
      grpc::ClientContext ctx;
      v1::MeshInfo info;
      return s.SetPositions(&ctx, r, &info);
    };
  };
  Positions nan = mesh_.positions;
  nan(5, 1) = std::nan("");
  Run({
      {"unknown mesh", set(mesh_.positions, std::nullopt, "m-nope"), Code::NOT_FOUND, "m-nope"},
      {"stale revision", set(mesh_.positions * 2.0, 7, id_), Code::ABORTED, "expected_revision 7"},
      {"too few vertices", set(mesh_.positions.topRows(10), std::nullopt, id_), Code::INVALID_ARGUMENT,
       "carried 10 vertices"},
      {"NaN coordinate", set(nan, std::nullopt, id_), Code::INVALID_ARGUMENT, "vertex 5"},
      {"no mesh id", set(mesh_.positions, std::nullopt, ""), Code::INVALID_ARGUMENT, "header.mesh_id"},
      {"wrong byte length",
       set(mesh_.positions, std::nullopt, id_,
           [](v1::SetPositionsRequest& r) { r.mutable_positions()->mutable_positions()->mutable_data()->pop_back(); }),
       Code::INVALID_ARGUMENT, "bytes"},
      {"offset not 0",
       set(mesh_.positions, std::nullopt, id_,
           [](v1::SetPositionsRequest& r) { r.mutable_positions()->set_vertex_offset(3); }),
       Code::INVALID_ARGUMENT, "vertex_offset is 3, expected 0"},
  });
}

TEST_F(BadInputTest, ReadsAndDeletes) {
  auto get = [](const std::string& id) {
    return [id](v1::GeomFit::Stub& s) {
      grpc::ClientContext ctx;
      v1::GetMeshRequest r;
      r.set_mesh_id(id);
      v1::MeshInfo info;
      return s.GetMesh(&ctx, r, &info);
    };
  };
  auto download = [](const std::string& id, int64_t revision) {
    return [=](v1::GeomFit::Stub& s) {
      grpc::ClientContext ctx;
      v1::DownloadMeshRequest r;
      r.set_mesh_id(id);
      r.set_revision(revision);
      auto reader = s.DownloadMesh(&ctx, r);
      v1::DownloadMeshResponse chunk;
      while (reader->Read(&chunk)) {
      }
      return reader->Finish();
    };
  };
  auto del = [](const std::string& id) {
    return [id](v1::GeomFit::Stub& s) {
      grpc::ClientContext ctx;
      v1::DeleteMeshRequest r;
      r.set_mesh_id(id);
      v1::DeleteMeshResponse out;
      return s.DeleteMesh(&ctx, r, &out);
    };
  };
  Run({
      {"get: empty id", get(""), Code::INVALID_ARGUMENT, "mesh_id"},
      {"get: unknown", get("m-unknown"), Code::NOT_FOUND, "m-unknown"},
      {"download: unknown", download("m-unknown", 0), Code::NOT_FOUND, "m-unknown"},
      {"download: negative revision", download(id_, -1), Code::INVALID_ARGUMENT, "negative"},
      {"download: stale revision", download(id_, 9), Code::NOT_FOUND, "revision 9"},
      {"list: page size",
       [](v1::GeomFit::Stub& s) {
         grpc::ClientContext ctx;
         v1::ListMeshesRequest r;
         r.set_page_size(-3);
         v1::ListMeshesResponse out;
         return s.ListMeshes(&ctx, r, &out);
       },
       Code::INVALID_ARGUMENT, "page_size"},
      {"delete: unknown", del("m-unknown"), Code::NOT_FOUND, "m-unknown"},
      {"delete: empty id", del(""), Code::INVALID_ARGUMENT, "mesh_id"},
  });
}

TEST_F(BadInputTest, ComputeDifferentials) {
  Run({
      {"unknown mesh", [&](auto& s) { return ComputeWith(s, [](auto& r) { r.set_mesh_id("m-zzz"); }); },
       Code::NOT_FOUND, "m-zzz"},
      {"degree 9", [&](auto& s) { return ComputeWith(s, [](auto& r) { r.mutable_options()->set_degree(9); }); },
       Code::INVALID_ARGUMENT, "degree"},
      {"unknown quantity", [&](auto& s) { return ComputeWith(s, [](auto& r) { r.add_quantities(static_cast<v1::Quantity>(99)); }); },
       Code::INVALID_ARGUMENT, "quantities[0]"},
      {"unknown method",
       [&](auto& s) { return ComputeWith(s, [](auto& r) { r.mutable_options()->set_method(static_cast<v1::FitMethod>(7)); }); },
       Code::INVALID_ARGUMENT, "options.method"},
      {"cond_threshold count",
       [&](auto& s) { return ComputeWith(s, [](auto& r) { r.mutable_options()->add_cond_threshold(10); }); },
       Code::INVALID_ARGUMENT, "cond_threshold"},
      {"stale revision", [&](auto& s) { return ComputeWith(s, [](auto& r) { r.set_revision(4); }); },
       Code::NOT_FOUND, "revision 4"},
      {"negative chunk rows", [&](auto& s) { return ComputeWith(s, [](auto& r) { r.set_chunk_rows(-1); }); },
       Code::INVALID_ARGUMENT, "negative"},
  });
}

}  // namespace
}  // namespace geomfit::server
