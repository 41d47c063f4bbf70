# flocklab: the job service (default command) and the batch CLI. docs/CONTAINER.md has it all.
#
#   docker build -t flocklab .                                   # CPU image
#   docker run -p 8000:8000 -v flocklab-data:/data flocklab       # serve on :8000
#   docker run --rm --user "$(id -u):$(id -g)" -v "$PWD:/out" flocklab \
#       flocklab run examples/vicsek.json --out /out/vicsek       # batch, written as you
#
# CUDA image: an nvidia/cuda runtime base; the driver comes from the host (--gpus all):
#   docker build --build-arg BASE_IMAGE=nvidia/cuda:12.6.3-runtime-ubuntu24.04 -t flocklab:cuda .
#   docker run --rm --gpus all flocklab:cuda python docker/probe_backend.py --backend cuda
#
# The build reads only this project's files (.dockerignore) and PyPI (pinned by
# constraints.txt). `RUN --mount=type=cache` needs BuildKit (Docker's default builder
# since 23.0), Buildah or Podman. Writable at run time: /data (job store, results) and
# /cache (Taichi's compile cache, warmed here for every model), both volumes.

# BASE_IMAGE: python:3.11-slim (CPU) or an nvidia/cuda runtime image (CUDA), see above.
ARG BASE_IMAGE=python:3.11-slim

FROM ${BASE_IMAGE}
# Taichi's extension links libX11 (manylinux lets wheels assume it); the slim image lacks
# it. A base without Python (the nvidia/cuda images: Ubuntu 24.04) gets its Python 3.12,
# for which constraints.txt's pins have wheels. Taichi's wheel carries its CUDA backend
# and needs only the driver's libcuda, which the NVIDIA runtime mounts for --gpus (the
# nvidia/cuda images already ask it for the compute capability).
RUN pkgs="libx11-6" \
 && { python3 -c "import ensurepip, venv" 2>/dev/null \
      || pkgs="$pkgs python3 python3-venv ca-certificates"; } \
 && apt-get update \
 && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends $pkgs \
 && rm -rf /var/lib/apt/lists/*

ARG FLOCKLAB_PORT=8000
ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    VIRTUAL_ENV=/opt/flocklab/venv \
    PATH=/opt/flocklab/venv/bin:$PATH
RUN useradd --create-home --uid 10001 --shell /usr/sbin/nologin flocklab

# A plain `pip install` of the project from its own files, every dependency pinned.
COPY . /tmp/src
RUN --mount=type=cache,target=/root/.cache/pip \
    python3 -m venv "$VIRTUAL_ENV" \
 && pip install --quiet -c /tmp/src/constraints.txt "/tmp/src[all]" \
 && mkdir -p /opt/flocklab/docker \
 && cp -r /tmp/src/examples /opt/flocklab/examples \
 && cp /tmp/src/docker/warm_cache.py /tmp/src/docker/probe_backend.py /opt/flocklab/docker/ \
 && rm -rf /tmp/src
WORKDIR /opt/flocklab

# Any uid may run the image (`--user "$(id -u):$(id -g)"` writes output as the caller):
# the caches are world-writable, and nothing else needs a home directory.
ENV FLOCKLAB_DATA_DIR=/data \
    FLOCKLAB_TAICHI_CACHE=/cache/taichi \
    XDG_CACHE_HOME=/cache \
    MPLCONFIGDIR=/cache/matplotlib \
    FLOCKLAB_HOST=0.0.0.0 \
    FLOCKLAB_PORT=${FLOCKLAB_PORT}

# Warm Taichi's offline cache with every model's kernels (fused and per-step paths), for
# the thread counts in WARM_THREADS (default: this build machine's cores; Taichi keys its
# cache by thread count), and matplotlib's font cache.
ARG WARM_THREADS=
RUN mkdir -p /data /cache/taichi /cache/matplotlib \
 && python docker/warm_cache.py examples ${WARM_THREADS:+--threads $WARM_THREADS} \
 && python -c "import matplotlib.pyplot" \
 && chown -R flocklab:flocklab /data \
 && chmod -R a+rwX /cache
USER flocklab

VOLUME ["/data", "/cache"]
EXPOSE ${FLOCKLAB_PORT}
# Liveness without curl and without touching Taichi: /healthz reads the job store only.
HEALTHCHECK --interval=30s --timeout=5s --start-period=30s --retries=3 \
  CMD ["python", "-c", "import os, sys, urllib.request; url = 'http://127.0.0.1:%s/healthz' % os.environ.get('FLOCKLAB_PORT', '8000'); sys.exit(0 if urllib.request.urlopen(url, timeout=4).status == 200 else 1)"]
CMD ["sh", "-c", "exec flocklab serve --host \"$FLOCKLAB_HOST\" --port \"$FLOCKLAB_PORT\""]
