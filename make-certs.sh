#!/bin/sh
# A certificate authority and one certificate (with its key) for a TLS Dask cluster:
# the scheduler, its workers and the clients that submit jobs all present it.
#
#   ./make-certs.sh DIR [DAYS]      # writes DIR/ca.pem, DIR/node.pem, DIR/node-key.pem
#
# Keep DIR/ca-key.pem off the cluster: it signs new certificates.
set -eu
dir=${1:?usage: make-certs.sh DIR [DAYS]}
days=${2:-365}
mkdir -p "$dir"
umask 077
openssl req -x509 -newkey rsa:3072 -nodes -days "$days" -subj "/CN=terrain cluster CA" \
  -keyout "$dir/ca-key.pem" -out "$dir/ca.pem" 2>/dev/null
openssl req -newkey rsa:3072 -nodes -subj "/CN=terrain cluster" \
  -keyout "$dir/node-key.pem" -out "$dir/node.csr" 2>/dev/null
openssl x509 -req -in "$dir/node.csr" -CA "$dir/ca.pem" -CAkey "$dir/ca-key.pem" -CAcreateserial \
  -days "$days" -out "$dir/node.pem" 2>/dev/null
rm -f "$dir/node.csr" "$dir/ca.srl"
chmod 644 "$dir/ca.pem" "$dir/node.pem"
echo "$dir: ca.pem, node.pem, node-key.pem (and ca-key.pem, which stays here)"
