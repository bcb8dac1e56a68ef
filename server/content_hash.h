#pragma once
// ContentHash moved to proto/ (shared with the clients, which predict mesh ids).
#include "proto/content_hash.h"

namespace geomfit::server {
using geomfit::ContentHash;
}  // namespace geomfit::server
