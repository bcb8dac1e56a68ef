#!/usr/bin/env bash
# Prints the Debian packages that own the shared libraries BINARY... load (ldd, then
# dpkg -S), one per line, sorted: the runtime image installs exactly these.
# Fails if a library belongs to no package (it would be missing at run time). The
# allocator comes this way too: geomfit-server links mimalloc, so libmimalloc2.0 is listed.
set -euo pipefail
libs=$(ldd "$@" | awk '/=> \// {print $3} /^\t\/.*\(0x/ {print $1}' | sort -u)
for lib in $libs; do
  # dpkg knows a file by the path its package installed it at; with merged /usr that
  # may be /lib/... or /usr/lib/... for the same file.
  found=""
  for p in "$lib" "$(readlink -f "$lib")" "${lib#/usr}" "/usr${lib}"; do
    if owner=$(dpkg -S "$p" 2>/dev/null); then found=${owner%%:*}; break; fi
  done
  [ -n "$found" ] || { echo "runtime-packages: no package owns $lib" >&2; exit 1; }
  echo "$found"
done | sort -u
