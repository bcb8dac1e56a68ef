#!/usr/bin/env bash
# Writes a throwaway CA and two certificates signed by it into DIR (for the TLS tests):
#   ca.pem ca.key, server.pem server.key (CN=localhost, SAN localhost and 127.0.0.1),
#   client.pem client.key (CN=tenant-a), other-ca.pem (a CA that signed nothing here).
set -euo pipefail
dir=${1:?usage: make_certs.sh DIR}
mkdir -p "$dir"
cd "$dir"
q() { openssl "$@" 2>/dev/null; }
q req -x509 -newkey rsa:2048 -nodes -days 2 -subj "/CN=geomfit test CA" -keyout ca.key -out ca.pem
q req -x509 -newkey rsa:2048 -nodes -days 2 -subj "/CN=other CA" -keyout other-ca.key -out other-ca.pem
sign() {  # NAME SUBJECT EXTENSIONS
  q req -newkey rsa:2048 -nodes -subj "$2" -keyout "$1.key" -out "$1.csr"
  printf '%s\n' "$3" > "$1.ext"
  q x509 -req -in "$1.csr" -CA ca.pem -CAkey ca.key -CAcreateserial -days 2 -extfile "$1.ext" -out "$1.pem"
  rm -f "$1.csr" "$1.ext"
}
sign server "/CN=localhost" "subjectAltName=DNS:localhost,IP:127.0.0.1
extendedKeyUsage=serverAuth"
sign client "/CN=tenant-a" "extendedKeyUsage=clientAuth"
chmod 600 ./*.key
