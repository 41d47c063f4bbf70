#!/usr/bin/env bash
# Make a local stand-in for the `python:3.11-slim` base image, for machines that reach no
# container registry: Debian bookworm (`debootstrap --variant=minbase`) with Debian's
# python3.11 and venv, imported into buildah's store as IMAGE (default
# localhost/python:3.11-slim). Python is /usr/bin/python3 here and /usr/local/bin/python3
# in the real image; the Dockerfile only calls `python3 -m venv`, which both have.
#
# The root filesystem is kept as a tarball in CACHE_DIR (default /var/cache/flocklab-image)
# so later runs import it in seconds instead of bootstrapping again (~3 minutes).
# The host's CA bundle is copied in: where HTTPS goes through an intercepting proxy, pip
# inside the build trusts what the host trusts. Needs root, debootstrap and buildah.
#
#   docker/make-base.sh [IMAGE]
set -euo pipefail
image="${1:-localhost/python:3.11-slim}"
cache="${FLOCKLAB_IMAGE_CACHE:-/var/cache/flocklab-image}"
mirror="${DEBIAN_MIRROR:-http://deb.debian.org/debian}"
tarball="$cache/bookworm-python3.11-minbase.tar"

mkdir -p "$cache"
if [[ ! -s "$tarball" ]]; then
    echo "make-base: no cached base; debootstrap --variant=minbase bookworm (a few minutes)"
    root="$(mktemp -d "$cache/rootfs.XXXXXX")"
    trap 'rm -rf "$root"' EXIT
    debootstrap --variant=minbase --include=python3,python3-venv,ca-certificates \
        bookworm "$root" "$mirror" >"$cache/debootstrap.log" 2>&1 \
        || { tail -20 "$cache/debootstrap.log"; exit 1; }
    cp /etc/ssl/certs/ca-certificates.crt "$root/etc/ssl/certs/ca-certificates.crt"
    rm -rf "$root"/var/cache/apt/archives/*.deb "$root"/var/lib/apt/lists/*
    tar -C "$root" --numeric-owner -cf "$tarball.partial" .
    mv "$tarball.partial" "$tarball"
else
    echo "make-base: using the cached base $tarball"
fi

# ADD of a tar extracts it: a scratch container, the rootfs added, committed as IMAGE.
ctr="$(buildah from scratch)"
buildah add --quiet "$ctr" "$tarball" / >/dev/null
buildah config --env LANG=C.UTF-8 \
    --env PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin \
    --env PIP_CERT=/etc/ssl/certs/ca-certificates.crt --cmd python3 "$ctr"
buildah commit --quiet --rm "$ctr" "$image" >/dev/null
echo "make-base: $image is a debootstrap stand-in for python:3.11-slim" \
     "(Debian bookworm minbase + python3.11 from Debian), not the official image"
