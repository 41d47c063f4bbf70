# flocklab: the job service (default) and the batch CLI, CPU image.
#
#   docker build -t flocklab .
#   docker run -p 8000:8000 -v flocklab-data:/data flocklab          # serve on :8000
#   docker run -v "$PWD:/data" flocklab flocklab run /data/scenario.json --out /data/out
#
# CUDA variant (Taichi's wheel carries its CUDA backend; the driver comes from the host
# through the NVIDIA Container Toolkit):
#   docker build --target cuda -t flocklab:cuda .
#   docker run --gpus all -p 8000:8000 flocklab:cuda     # scenarios with "backend": "cuda"
#
# Hardened run: docker run --read-only --tmpfs /tmp -v flocklab-data:/data \
#   -v flocklab-cache:/cache -p 8000:8000 flocklab
# Only /data (jobs.sqlite3, results/) and /cache (Taichi's compile cache) are written.
# The build reads nothing but this project's files (see .dockerignore) and PyPI.

ARG PYTHON_IMAGE=python:3.11-slim

FROM ${PYTHON_IMAGE} AS cpu
ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1
RUN useradd --create-home --uid 10001 --shell /usr/sbin/nologin flocklab
WORKDIR /opt/flocklab
COPY pyproject.toml README.md ./
COPY schemas ./schemas
COPY kernels ./kernels
COPY service ./service
COPY clients ./clients
RUN pip install ".[all]" && rm -rf build *.egg-info

ENV FLOCKLAB_DATA_DIR=/data \
    FLOCKLAB_TAICHI_CACHE=/cache/taichi \
    XDG_CACHE_HOME=/cache \
    TI_LOG_LEVEL=warn
RUN mkdir -p /data /cache/taichi && chown -R flocklab:flocklab /data /cache
USER flocklab

# Warm Taichi's offline compile cache: a tiny run compiles (and caches) the kernels, so
# the first job of a fresh container skips most of its compile time.
RUN printf '%s' '{"model": {"kind": "vicsek", "eta": 0.5}, "space": {"kind": "periodic", "L": 4}, "neighbours": {"radius": 1}, "initial": {"kind": "random", "N": 64}, "time": {"steps": 3}, "recording": {"every": 1, "arrays": ["position", "heading"]}}' > /tmp/warm.json \
 && flocklab run /tmp/warm.json --out /tmp/warm-out \
 && rm -rf /tmp/warm.json /tmp/warm-out

VOLUME ["/data"]
EXPOSE 8000
# Liveness without curl and without touching Taichi: /healthz reads the job store only.
HEALTHCHECK --interval=30s --timeout=5s --start-period=30s --retries=3 \
  CMD ["python", "-c", "import sys, urllib.request; sys.exit(0 if urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=4).status == 200 else 1)"]
CMD ["flocklab", "serve", "--host", "0.0.0.0", "--port", "8000"]

FROM cpu AS cuda
# The NVIDIA runtime mounts the host's driver (libcuda) into containers started with
# --gpus; these tell it which driver capabilities Taichi needs.
ENV NVIDIA_VISIBLE_DEVICES=all \
    NVIDIA_DRIVER_CAPABILITIES=compute,utility

# The default target is the CPU image.
FROM cpu
