#!/usr/bin/env bash
# Make a local certificate authority and certificates for testing Zenoh over TLS.
# Usage: deploy/tls/make-certs.sh [OUT_DIR] [ROUTER_NAME]
#   OUT_DIR      where to write (default: deploy/tls/out)
#   ROUTER_NAME  the name clients use to reach the router (default: localhost);
#                it goes in the router certificate's subjectAltName.
# Writes ca.pem/ca.key, router.pem/router.key (server) and client.pem/client.key
# (for mutual TLS). For production, use your organisation's CA instead.
set -euo pipefail
out="${1:-$(dirname "$0")/out}"
name="${2:-localhost}"
mkdir -p "$out"
cd "$out"
days=365
openssl req -x509 -newkey rsa:2048 -nodes -keyout ca.key -out ca.pem -days "$days" \
  -subj "/CN=blackmetal test CA" 2>/dev/null
make_cert() {  # NAME CN SAN
  openssl req -newkey rsa:2048 -nodes -keyout "$1.key" -out "$1.csr" -subj "/CN=$2" 2>/dev/null
  printf 'subjectAltName=%s\nextendedKeyUsage=serverAuth,clientAuth\n' "$3" > "$1.ext"
  openssl x509 -req -in "$1.csr" -CA ca.pem -CAkey ca.key -CAcreateserial -out "$1.pem" \
    -days "$days" -extfile "$1.ext" 2>/dev/null
  rm -f "$1.csr" "$1.ext"
}
make_cert router "$name" "DNS:$name,DNS:localhost,IP:127.0.0.1"
make_cert client "blackmetal-client" "DNS:blackmetal-client"
chmod 600 ./*.key
echo "wrote CA, router and client certificates to $out"
