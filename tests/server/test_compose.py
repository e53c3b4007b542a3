"""The deployment files: docker-compose.yml (parsed with PyYAML) and the Dockerfile.

No Docker engine runs in the tests; these check the structure the DESIGN asks for
(redis, api, N scalable workers, one shared artifact volume) and the image's essentials.
"""
from __future__ import annotations

import re
import shlex
import tomllib
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
REDIS_URL = "redis://redis:6379/0"


@pytest.fixture(scope="module")
def compose() -> dict:
    return yaml.safe_load((ROOT / "docker-compose.yml").read_text())


@pytest.fixture(scope="module")
def dockerfile() -> list[str]:
    """Dockerfile instructions, continuation lines joined, comments dropped."""
    text = (ROOT / "Dockerfile").read_text()
    text = re.sub(r"\\\n", " ", text)
    return [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]


def argv(command) -> list[str]:
    return shlex.split(command) if isinstance(command, str) else list(command)


def env(service: dict) -> dict[str, str]:
    e = service.get("environment", {})
    if isinstance(e, list):
        e = dict(item.split("=", 1) for item in e)
    return e


def mounts(service: dict) -> dict[str, str]:
    """target -> source for short-syntax and long-syntax volume entries."""
    out = {}
    for v in service.get("volumes", []):
        if isinstance(v, str):
            source, target = v.split(":")[:2]
        else:
            source, target = v["source"], v["target"]
        out[target] = source
    return out


def test_services(compose):
    assert set(compose["services"]) == {"redis", "api", "worker"}


def test_redis(compose):
    redis = compose["services"]["redis"]
    assert redis["image"].split(":") == ["redis", "7"]
    cmd = argv(redis["command"])
    assert cmd[0] == "redis-server" and cmd[cmd.index("--appendonly") + 1] == "yes"
    assert "kiln-data" not in mounts(redis).values()


def test_api(compose):
    api = compose["services"]["api"]
    assert argv(api["command"]) == ["kiln", "api", "--host", "0.0.0.0", "--port", "8000", "--data", "/data"]
    e = env(api)
    assert e["REDIS_URL"] == REDIS_URL
    # Required from the host environment: without keys the api refuses a non-loopback bind.
    assert re.fullmatch(r"\$\{KILN_API_KEYS:\?[^}]+\}", e["KILN_API_KEYS"])
    assert [str(p) for p in api["ports"]] == ["8000:8000"]
    assert "redis" in api["depends_on"]
    assert "build" in api


def test_worker_scales(compose):
    worker = compose["services"]["worker"]
    assert argv(worker["command"]) == ["kiln", "worker", "--data", "/data"]
    assert env(worker)["REDIS_URL"] == REDIS_URL
    assert "KILN_API_KEYS" not in env(worker)
    # `docker compose up --scale worker=N` needs no fixed name and no host ports.
    for key in ("container_name", "ports", "hostname"):
        assert key not in worker
    assert "redis" in worker["depends_on"]
    assert worker.get("healthcheck", {}).get("disable") is True  # the image's probe is the api's
    assert worker["image"] == compose["services"]["api"]["image"]  # one image for both


def test_shared_volume(compose):
    assert "kiln-data" in compose["volumes"]
    for name in ("api", "worker"):
        assert mounts(compose["services"][name])["/data"] == "kiln-data", name


def test_console_script_matches(compose):
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert "kiln" in project["scripts"]
    assert project["requires-python"] == ">=3.11"


def test_dockerfile(dockerfile):
    instr = [ln.split(None, 1) for ln in dockerfile]
    ops = [op.upper() for op, *_ in instr]
    assert dockerfile[0] == "FROM python:3.11-slim"
    apt = next(ln for ln in dockerfile if "apt-get install" in ln)
    for pkg in ("libegl1", "libgl1", "libgomp1"):
        assert re.search(rf"\b{pkg}\b", apt), pkg
    assert "rm -rf /var/lib/apt/lists/*" in apt
    pip = [i for i, ln in enumerate(dockerfile) if re.search(r"\bpip install\b.*\s\"?\.(\[[a-z,]+\])?\"?(\s|$)", ln)]
    assert len(pip) == 1
    extras = re.search(r"\.\[([a-z,]+)\]", dockerfile[pip[0]])        # what serving needs (pyproject extras)
    assert extras and set(extras.group(1).split(",")) == {"api", "worker", "render"}, dockerfile[pip[0]]
    users = [i for i, op in enumerate(ops) if op == "USER"]
    assert users and users[-1] > pip[0]  # installs as root, runs as the user
    final_user = dockerfile[users[-1]].split()[1]
    assert final_user not in ("root", "0") and not final_user.startswith("0:")
    assert any(re.search(rf"useradd\b.*\b{final_user}\b", ln) for ln in dockerfile)
    health = [ln for ln in dockerfile if ln.upper().startswith("HEALTHCHECK")]
    assert len(health) == 1 and "/healthz" in health[0] and ":8000" in health[0]
    assert any(op == "EXPOSE" and "8000" in rest[0] for op, *rest in instr)
    # What the image copies must exist, so the build context is right.
    for op, *rest in instr:
        if op.upper() == "COPY":
            for src in rest[0].split()[:-1]:
                assert (ROOT / src).exists(), src


def test_extras_hold_each_dependency_where_it_is_used():
    """pyproject's extras: the test extra pulls what serving needs (so scripts/test.sh on a fresh checkout has it),
    the dependencies only tests import sit in test alone, and the scripts install the right extras."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = project["optional-dependencies"]
    assert set(extras) == {"api", "worker", "render", "test"}
    assert "kiln-bake[api,worker,render]" in extras["test"]

    def names(reqs):
        return {re.match(r"[A-Za-z0-9_.-]+", r).group(0).lower() for r in reqs}
    runtime = names(project["dependencies"]) | names(extras["api"]) | names(extras["worker"]) | names(extras["render"])
    for test_only in ("trimesh", "psutil", "pyyaml", "pytest"):
        assert test_only not in runtime and test_only in names(extras["test"]), test_only
    assert "tomli-w" not in runtime | names(extras["test"])           # nothing imports it
    setup = (ROOT / "scripts" / "setup.sh").read_text()
    assert 'EXTRAS=${KILN_EXTRAS:-test}' in setup and 'pip install -q -e ".[$EXTRAS]"' in setup
    assert "KILN_EXTRAS=${KILN_EXTRAS:-api,worker,render} bash scripts/setup.sh" in (ROOT / "scripts" / "serve.sh"
                                                                                     ).read_text()
