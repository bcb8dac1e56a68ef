#include "server/options.h"

#include <cstdlib>

#include <gtest/gtest.h>

namespace geomfit::server {
namespace {

TEST(OptionsTest, DefaultsFlagsAndEnvironment) {
  auto d = ParseServerOptions({});
  ASSERT_TRUE(d.ok());
  EXPECT_EQ(d->max_message_bytes, 64 << 20);
  EXPECT_EQ(d->store, "sqlite");
  EXPECT_EQ(d->spin_us, 1000);

  ::setenv("GEOMFIT_CACHE_BYTES", "32M", 1);
  ::setenv("GEOMFIT_PORT", "7000", 1);
  auto o = ParseServerOptions({"--port=7001", "--store", "memory", "--max-vertices=1000"});
  ::unsetenv("GEOMFIT_CACHE_BYTES");
  ::unsetenv("GEOMFIT_PORT");
  ASSERT_TRUE(o.ok()) << o.status();
  EXPECT_EQ(o->port, 7001) << "flags win over the environment";
  EXPECT_EQ(o->cache_bytes, 32 << 20);
  EXPECT_EQ(o->store, "memory");
  EXPECT_EQ(o->max_vertices, 1000);
}

TEST(OptionsTest, LogFormat) {
  auto d = ParseServerOptions({});
  ASSERT_TRUE(d.ok());
  EXPECT_EQ(d->log_format, "text");
  ::setenv("GEOMFIT_LOG_FORMAT", "json", 1);
  auto o = ParseServerOptions({});
  ::unsetenv("GEOMFIT_LOG_FORMAT");
  ASSERT_TRUE(o.ok()) << o.status();
  EXPECT_EQ(o->log_format, "json");
  o = ParseServerOptions({"--log-format", "json"});
  ASSERT_TRUE(o.ok()) << o.status();
  EXPECT_EQ(o->log_format, "json");
  EXPECT_NE(ServerUsage().find("GEOMFIT_LOG_FORMAT"), std::string::npos);
}

TEST(OptionsTest, BadValuesNameTheFlag) {
  auto r = ParseServerOptions({"--store=postgres"});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("--store=postgres"), std::string::npos) << r.status();
  r = ParseServerOptions({"--port=70000"});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("--port"), std::string::npos);
  r = ParseServerOptions({"--log-level=loud"});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("--log-level=loud"), std::string::npos);
  r = ParseServerOptions({"--log-format=xml"});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("--log-format=xml"), std::string::npos) << r.status();
  r = ParseServerOptions({"--spin-us=-1"});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("--spin-us"), std::string::npos);
  r = ParseServerOptions({"--frobnicate=1"});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("--frobnicate"), std::string::npos);
  ::setenv("GEOMFIT_WORKERS", "zero", 1);
  r = ParseServerOptions({});
  ::unsetenv("GEOMFIT_WORKERS");
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("GEOMFIT_WORKERS"), std::string::npos) << r.status();
}

TEST(OptionsTest, Quotas) {
  auto d = ParseServerOptions({});
  ASSERT_TRUE(d.ok());
  EXPECT_EQ(d->quota_meshes, 0) << "unlimited by default";
  EXPECT_EQ(d->quota_bytes, 0);
  EXPECT_EQ(d->quota_inflight, 0);
  ::setenv("GEOMFIT_QUOTA_MESHES", "12", 1);
  auto o = ParseServerOptions({"--quota-bytes=3G", "--quota-inflight", "4"});
  ::unsetenv("GEOMFIT_QUOTA_MESHES");
  ASSERT_TRUE(o.ok()) << o.status();
  EXPECT_EQ(o->quota_meshes, 12);
  EXPECT_EQ(o->quota_bytes, int64_t{3} << 30);
  EXPECT_EQ(o->quota_inflight, 4);
  auto r = ParseServerOptions({"--quota-inflight=-1"});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("--quota-inflight=-1"), std::string::npos) << r.status();
}

}  // namespace
}  // namespace geomfit::server
