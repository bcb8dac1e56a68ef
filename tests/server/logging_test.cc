// --log-format=json: one JSON object per line, the message escaped.
#include "server/logging.h"

#include <gtest/gtest.h>
#include <spdlog/details/log_msg.h>

namespace geomfit::server {
namespace {

TEST(LoggingTest, JsonEscapesQuotesBackslashesAndControlCharacters) {
  EXPECT_EQ(JsonEscape("plain text"), "plain text");
  EXPECT_EQ(JsonEscape("a \"quoted\" C:\\path"), "a \\\"quoted\\\" C:\\\\path");
  EXPECT_EQ(JsonEscape("line 1\nline 2\r\tend"), "line 1\\nline 2\\r\\tend");
  EXPECT_EQ(JsonEscape(std::string("bell\x07 nul", 9) + std::string(1, '\0')), "bell\\u0007 nul\\u0000");
  EXPECT_EQ(JsonEscape("\xc3\xa9t\xc3\xa9"), "\xc3\xa9t\xc3\xa9") << "UTF-8 passes through";
}

TEST(LoggingTest, JsonLineHasTimeLevelLoggerThreadAndMessage) {
  // 2026-01-02T03:04:05.678Z
  const auto t = spdlog::log_clock::time_point(std::chrono::milliseconds(int64_t{1767323045678}));
  spdlog::details::log_msg msg(t, spdlog::source_loc{}, "geomfit-server", spdlog::level::warn,
                               "mesh \"m-1\" not found\nnext");
  msg.thread_id = 42;
  spdlog::memory_buf_t buf;
  NewJsonLogFormatter()->format(msg, buf);
  EXPECT_EQ(std::string(buf.data(), buf.size()),
            "{\"time\":\"2026-01-02T03:04:05.678Z\",\"level\":\"warning\",\"logger\":\"geomfit-server\","
            "\"thread\":42,\"message\":\"mesh \\\"m-1\\\" not found\\nnext\"}\n");
  spdlog::memory_buf_t again;
  NewJsonLogFormatter()->clone()->format(msg, again);
  EXPECT_EQ(std::string(again.data(), again.size()), std::string(buf.data(), buf.size()));
}

}  // namespace
}  // namespace geomfit::server
