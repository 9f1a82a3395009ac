# The terrain image: the project installed, its numba kernels compiled at build time.
FROM python:3.11-slim

ENV PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    NUMBA_CACHE_DIR=/opt/terrain/.numba-cache

WORKDIR /opt/terrain
COPY pyproject.toml README.md ./
COPY meshcore ./meshcore
COPY pipeline ./pipeline
COPY workflows ./workflows
RUN pip install . \
 && python -c "import numpy as np, meshcore; m = meshcore.build_mesh(np.random.default_rng(0).random((500, 2)), 's3', 's4', window=(0.2, 0.2, 0.8, 0.8)); meshcore.rasterize(m, m.vertices[:, 0], 0, 0, 0.1, 10, 10)" \
 && chmod -R a+rwX /opt/terrain/.numba-cache

# the scheduler, workers and the runner all use this image (see docker-compose.yml)
CMD ["terrain", "--help"]
