"""scripts/setup.sh waits for a held apt/dpkg lock (scripts/apt_lock.sh) instead of failing: with fake
`apt-get` and `fuser` on PATH, bounded by KILN_APT_LOCK_WAIT, polling every KILN_APT_LOCK_POLL seconds."""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _fake_bin(tmp_path: Path, apt_script: str, fuser_script: str = "exit 1\n") -> dict:
    """Fake apt-get and fuser first on PATH (the default fuser sees no holder: only apt-get's message tells)."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "apt-get").write_text("#!/bin/bash\n" + apt_script)
    (bin_dir / "apt-get").chmod(0o755)
    (bin_dir / "fuser").write_text("#!/bin/bash\n" + fuser_script)
    (bin_dir / "fuser").chmod(0o755)
    lock = tmp_path / "lock-frontend"
    lock.write_text("")
    env = {**os.environ, "PATH": f"{bin_dir}:/usr/bin:/bin", "KILN_APT_LOCK_POLL": "0.1",
           "KILN_APT_LOCKS": str(lock), "STATE": str(tmp_path / "state")}
    return env


def _run(env: dict, *args: str) -> subprocess.CompletedProcess:
    script = f". {ROOT / 'scripts' / 'apt_lock.sh'}; apt_get {' '.join(args)}"
    return subprocess.run(["bash", "-c", script], env=env, capture_output=True, text=True, timeout=60, cwd=ROOT)


# apt-get that fails with the lock message on its first N runs, then succeeds
_BUSY_THEN_OK = """
n=$(cat "$STATE" 2>/dev/null || echo 0); echo $((n + 1)) > "$STATE"
if [ "$n" -lt 2 ]; then
  echo "E: Could not get lock /var/lib/dpkg/lock-frontend. It is held by process 4242 (apt-get)" >&2
  echo "E: Unable to acquire the dpkg frontend lock (/var/lib/dpkg/lock-frontend), is another process using it?" >&2
  exit 100
fi
echo "installed $*"
"""


def test_retries_while_apt_get_cannot_get_the_lock(tmp_path):
    env = _fake_bin(tmp_path, _BUSY_THEN_OK)
    r = _run(env, "install", "-y", "chromium")
    assert r.returncode == 0, r.stderr
    assert "installed install -y chromium" in r.stdout
    assert r.stderr.count("could not get the apt/dpkg lock") == 2, r.stderr
    assert (tmp_path / "state").read_text().strip() == "3"


def test_waits_while_fuser_sees_a_holder(tmp_path):
    # the lock is held for the first three checks (fuser prints a pid), then free
    fuser = 'n=$(cat "$STATE.f" 2>/dev/null || echo 0); echo $((n + 1)) > "$STATE.f"; if [ "$n" -lt 3 ]; then echo " 4242"; exit 0; fi; exit 1\n'
    env = _fake_bin(tmp_path, 'echo "ran $*"\n', fuser)
    r = _run(env, "update", "-qq")
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "ran update -qq"
    assert r.stderr.count("another process holds the apt/dpkg lock (pid 4242)") == 3, r.stderr


def test_gives_up_after_the_bound_with_apt_gets_message(tmp_path):
    env = _fake_bin(tmp_path, 'echo "E: Could not get lock /var/lib/dpkg/lock-frontend" >&2; exit 100\n')
    env["KILN_APT_LOCK_WAIT"] = "1"
    r = _run(env, "install", "-y", "x")
    assert r.returncode == 100
    assert "giving up" in r.stderr and "Could not get lock" in r.stderr


def test_other_failures_are_not_retried(tmp_path):
    env = _fake_bin(tmp_path, 'n=$(cat "$STATE" 2>/dev/null || echo 0); echo $((n + 1)) > "$STATE"; '
                              'echo "E: Unable to locate package nosuch" >&2; exit 100\n')
    r = _run(env, "install", "-y", "nosuch")
    assert r.returncode == 100 and "Unable to locate package" in r.stderr
    assert (tmp_path / "state").read_text().strip() == "1"


@pytest.mark.parametrize("line", ["apt_get update -qq", "apt_get install -y -qq --no-install-recommends"])
def test_setup_sh_uses_the_waiting_apt_get(line):
    text = (ROOT / "scripts" / "setup.sh").read_text()
    assert ". scripts/apt_lock.sh" in text and line in text
    assert "DEBIAN_FRONTEND=noninteractive apt-get" not in text
