# Kiln: one image for the API server and the bake workers (docker-compose.yml runs both).
#   docker build -t kiln .
#   docker run -e KILN_API_KEYS=team:longsecretkey -p 8000:8000 kiln          # api (the default command)
#   docker run -e REDIS_URL=redis://host:6379/0 kiln kiln worker --data /data  # a worker
FROM python:3.11-slim

# EGL/GL for the headless moderngl renderer (evaluate stage); OpenMP for Embree and numpy kernels.
RUN apt-get update \
    && apt-get install -y --no-install-recommends libegl1 libgl1 libgomp1 \
    && rm -rf /var/lib/apt/lists/*

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    KILN_DATA=/data

WORKDIR /app
# Only what the package needs (no .venv, tests or data in the image).
COPY pyproject.toml ./
COPY proto ./proto
COPY persist ./persist
COPY workers ./workers
COPY server ./server
RUN pip install --no-cache-dir ".[api,worker,render]" \
    && rm -rf build *.egg-info

# Non-root; /data is created owned by that user so a fresh named volume mounted there inherits it.
RUN useradd --create-home --uid 10001 --user-group kiln \
    && mkdir -p /data \
    && chown kiln:kiln /data
USER kiln
VOLUME ["/data"]
WORKDIR /home/kiln

EXPOSE 8000
# The API's liveness probe; docker-compose.yml disables it for workers (they serve no HTTP).
HEALTHCHECK --interval=30s --timeout=5s --start-period=20s --retries=3 \
    CMD ["python", "-c", "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=4)"]

CMD ["kiln", "api", "--host", "0.0.0.0", "--port", "8000", "--data", "/data"]
