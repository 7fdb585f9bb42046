# hptvsim service image: the API with its dashboard and worker processes, the viser live view,
# and (with docker-compose's "ray" profile) Ray head and worker nodes. CPU only.
#
#   docker build -t hptvsim .
#   docker run -p 8000:8000 -p 8080:8080 hptvsim          # SQLite inside the container
FROM python:3.11-slim-bookworm

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    OMP_NUM_THREADS=1 \
    PYTHONPATH=/app \
    HPTVSIM_DATA_DIR=/data \
    HPTVSIM_HOST=0.0.0.0

# a C compiler: the sonar and task kernels and the FMUs' binaries are built from source on first use
RUN apt-get update \
    && apt-get install -y --no-install-recommends build-essential curl \
    && rm -rf /var/lib/apt/lists/*

WORKDIR /app

# torch first and exactly, from the CPU index (the default index would pull several GB of CUDA)
RUN pip install "torch==2.13.0" --index-url https://download.pytorch.org/whl/cpu

# dependencies before the sources, so code changes do not reinstall them (read from pyproject.toml;
# torch==2.13.0 there is satisfied by the CPU build above)
COPY pyproject.toml README.md ./
RUN python -c "import tomllib; p = tomllib.load(open('pyproject.toml', 'rb'))['project']; \
extras = p['optional-dependencies']; \
print('\n'.join(p['dependencies'] + [r for k in ('rl', 'world', 'offline', 'service', 'ray') for r in extras[k]]))" \
    > /tmp/requirements.txt \
    && pip install -r /tmp/requirements.txt "psycopg[binary]>=3.2"

COPY hptvsim ./hptvsim
COPY services ./services
COPY web ./web
COPY fmus ./fmus
COPY scenarios ./scenarios
COPY configs ./configs
# the shipped trained policies (MAISAC pursuers and evader, the defaults of the service)
COPY policies ./policies
RUN pip install --no-deps -e . \
    && python -c "import hptvsim.envs, services.app"

RUN useradd --create-home --uid 1000 hptvsim \
    && mkdir -p /data \
    && chown -R hptvsim /data /app
USER hptvsim
# compile the C kernels into the user's cache now rather than at the first episode
RUN python -c "from hptvsim.envs import GameCore; GameCore('goto_tiny').close()"
VOLUME ["/data"]
EXPOSE 8000 8080

HEALTHCHECK --interval=15s --timeout=5s --start-period=30s \
    CMD curl -fsS http://127.0.0.1:8000/healthz || exit 1

CMD ["python", "-m", "services", "--host", "0.0.0.0", "--port", "8000", "--viser-port", "8080"]
