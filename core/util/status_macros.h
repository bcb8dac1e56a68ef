#pragma once
// Abseil 20220623 (Debian 12) ships no RETURN_IF_ERROR / ASSIGN_OR_RETURN; these are ours.
#include "absl/status/status.h"
#include "absl/status/statusor.h"

#define GF_CONCAT_INNER_(a, b) a##b
#define GF_CONCAT_(a, b) GF_CONCAT_INNER_(a, b)

/// Returns the status from the enclosing function if `expr` is not OK.
#define GF_RETURN_IF_ERROR(expr)                  \
  do {                                            \
    const ::absl::Status gf_status_ = (expr);     \
    if (!gf_status_.ok()) return gf_status_;      \
  } while (false)

/// `GF_ASSIGN_OR_RETURN(auto x, Foo());` unwraps a StatusOr or returns its status.
#define GF_ASSIGN_OR_RETURN(lhs, expr) \
  GF_ASSIGN_OR_RETURN_IMPL_(GF_CONCAT_(gf_statusor_, __LINE__), lhs, expr)
#define GF_ASSIGN_OR_RETURN_IMPL_(tmp, lhs, expr) \
  auto tmp = (expr);                              \
  if (!tmp.ok()) return tmp.status();             \
  lhs = std::move(tmp).value()
