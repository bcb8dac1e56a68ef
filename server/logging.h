#pragma once
#include <memory>
#include <string>
#include <string_view>

#include <spdlog/formatter.h>

namespace geomfit::server {

/// One JSON object per log line, for cluster log collectors (--log-format=json):
/// {"time":"2026-01-02T03:04:05.678Z","level":"info","logger":"geomfit-server",
///  "thread":123,"message":"..."}; the message is escaped (quotes, backslashes,
/// control characters), the time is UTC with milliseconds.
std::unique_ptr<spdlog::formatter> NewJsonLogFormatter();

/// `text` escaped as the contents of a JSON string (without the quotes).
std::string JsonEscape(std::string_view text);

}  // namespace geomfit::server
