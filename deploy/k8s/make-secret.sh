#!/bin/sh
# Makes the cluster's shared secret and the Kubernetes Secret that holds it
# (deploy/README.md, "Kubernetes"): 32 fresh random bytes, base64, written
# to FILE (default ./texsyn-secret, mode 600; it must not exist yet), then
#   kubectl -n NAMESPACE create secret generic texsyn-secret --from-file=secret=FILE
# Clients outside the cluster pass the same file: texsyn ... --secret-file FILE.
# No secret is shipped in deploy/k8s: a fixed one in the files would be
# installed by `kubectl apply -f deploy/k8s/` and known to everyone.
# Usage: deploy/k8s/make-secret.sh [FILE [NAMESPACE]]
set -eu
file=${1:-texsyn-secret}
ns=${2:-texsyn}
if [ -e "$file" ]; then
  echo "make-secret.sh: $file exists; remove it first, or give another FILE" >&2
  exit 1
fi
umask 077
head -c 32 /dev/urandom | base64 > "$file"
kubectl -n "$ns" create secret generic texsyn-secret --from-file=secret="$file"
echo "make-secret.sh: the secret is in $file (mode 600) and in Secret $ns/texsyn-secret"
