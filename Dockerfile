# syntax=docker/dockerfile:1
# hptvsim service image: the API with its dashboard and worker processes, the viser live view,
# and (with docker-compose's "ray" profile) Ray head and worker nodes. CPU only.
#
#   docker build -t hptvsim .
#   docker run -e HPTVSIM_API_KEY=... -p 8000:8000 -p 8080:8080 hptvsim    # SQLite inside the container
#
# The image binds 0.0.0.0, so it refuses to start without HPTVSIM_API_KEY: every port it opens
# (the API and the live view) then asks for the key.
FROM python:3.11-slim-bookworm

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    OMP_NUM_THREADS=1 \
    HPTVSIM_DATA_DIR=/data \
    HPTVSIM_HOST=0.0.0.0

# a C compiler: the sonar, error and task kernels are compiled from their C sources on first use
RUN apt-get update \
    && apt-get install -y --no-install-recommends build-essential curl \
    && rm -rf /var/lib/apt/lists/*

WORKDIR /src

# torch first and exactly, from the CPU index (the default index would pull several GB of CUDA)
RUN pip install "torch==2.13.0" --index-url https://download.pytorch.org/whl/cpu

# dependencies before the sources, so code changes do not reinstall them: the service and ray
# extras of pyproject.toml, with the extras they name of hptvsim itself expanded
# (torch==2.13.0 there is satisfied by the CPU build above)
COPY pyproject.toml README.md ./
RUN python - > /tmp/requirements.txt <<'PY'
import re, tomllib
p = tomllib.load(open("pyproject.toml", "rb"))["project"]
extras, seen, out = p["optional-dependencies"], set(), list(p["dependencies"])
todo = ["service", "ray"]
while todo:
    name = todo.pop()
    if name in seen:
        continue
    seen.add(name)
    for req in extras[name]:
        m = re.fullmatch(r"hptvsim\[(.+)\]", req)
        if m:
            todo += [e.strip() for e in m.group(1).split(",")]
        else:
            out.append(req)
print("\n".join(out))
PY
RUN pip install -r /tmp/requirements.txt

# the package itself, installed as users install it: a wheel with the FMUs, scenarios, configs,
# shipped policies and the dashboard inside
COPY hptvsim ./hptvsim
COPY web ./web
COPY fmus ./fmus
COPY scenarios ./scenarios
COPY configs ./configs
COPY policies ./policies
RUN pip install --no-deps . && rm -rf /src

RUN useradd --create-home --uid 1000 hptvsim \
    && mkdir -p /data \
    && chown -R hptvsim /data
USER hptvsim
WORKDIR /home/hptvsim
# compile the C kernels into the user's cache now rather than at the first episode
RUN python -c "from hptvsim.envs import GameCore; GameCore('goto_tiny').close()"
VOLUME ["/data"]
EXPOSE 8000 8080

HEALTHCHECK --interval=15s --timeout=5s --start-period=30s \
    CMD curl -fsS http://127.0.0.1:8000/healthz || exit 1

CMD ["hptvsim", "serve", "--host", "0.0.0.0", "--port", "8000", "--viser-port", "8080"]
