# The terrain image: the project installed, its numba kernels compiled at build time.
FROM python:3.11-slim

ENV PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    NUMBA_CACHE_DIR=/opt/terrain/.numba-cache

WORKDIR /opt/terrain
COPY pyproject.toml README.md ./
COPY meshcore ./meshcore
COPY experiments ./experiments
COPY pipeline ./pipeline
COPY workflows ./workflows
# the demo job runs every kernel of a run (routing, hull, mesh, DEM): about
# 25 s of compiling that each container would otherwise pay on its first job
RUN pip install ".[cluster,cloud]" \
 && terrain demo --out /tmp/warm-up > /dev/null \
 && rm -rf /tmp/warm-up \
 && chmod -R a+rwX /opt/terrain/.numba-cache

# the scheduler, workers and the runner all use this image (see docker-compose.yml)
CMD ["terrain", "--help"]
