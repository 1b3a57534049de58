"""Shared fixtures: the repository's committed Blender frames and a real `afterimage serve`.

The server tests need the afterimage binary: AFTERIMAGE_BIN names it (check.sh sets it).
Without it they are skipped, unless AFTERIMAGE_REQUIRE_SERVER=1 (CI), which makes a
missing binary a failure instead.
"""

import os
import shutil
import socket
import subprocess
import sys
import time

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", "..", ".."))
FIXTURES = os.environ.get("AFTERIMAGE_FIXTURES", os.path.join(ROOT, "tests", "fixtures"))
FENCE = os.path.join(FIXTURES, "blender-fence", "input")
MOTION = os.path.join(FIXTURES, "blender-motion")


@pytest.fixture(scope="session")
def fixtures_dir():
    if not os.path.isdir(FENCE):
        pytest.fail(f"the committed Blender fixtures are not at {FIXTURES} (set AFTERIMAGE_FIXTURES)")
    return FIXTURES


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="session")
def afterimage_bin():
    path = os.environ.get("AFTERIMAGE_BIN")
    if not path or not os.access(path, os.X_OK):
        msg = f"no afterimage binary (AFTERIMAGE_BIN={path!r})"
        if os.environ.get("AFTERIMAGE_REQUIRE_SERVER") == "1":
            pytest.fail(msg + " and AFTERIMAGE_REQUIRE_SERVER=1")
        pytest.skip(msg)
    return path


@pytest.fixture(scope="session")
def server(afterimage_bin, tmp_path_factory):
    """A running `afterimage serve` on loopback ports; yields its gRPC address."""
    grpc_port, http_port = _free_port(), _free_port()
    addr = f"127.0.0.1:{grpc_port}"
    log = tmp_path_factory.mktemp("server") / "serve.log"
    env = dict(os.environ, AFTERIMAGE_GRPC_ADDR=addr, AFTERIMAGE_HTTP_ADDR=f"127.0.0.1:{http_port}")
    env.pop("AFTERIMAGE_API_KEYS", None)
    with open(log, "w") as out:
        proc = subprocess.Popen([afterimage_bin, "serve"], env=env, stdout=out, stderr=subprocess.STDOUT)
    try:
        deadline = time.time() + 30
        while True:
            if proc.poll() is not None:
                pytest.fail(f"afterimage serve exited with {proc.returncode}: {open(log).read()}")
            try:
                socket.create_connection(("127.0.0.1", grpc_port), timeout=0.5).close()
                break
            except OSError:
                if time.time() > deadline:
                    pytest.fail(f"afterimage serve did not listen on {addr} within 30 s: {open(log).read()}")
                time.sleep(0.1)
        yield addr
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()


def run_cli(*args, timeout=120):
    """Runs `python -m afterimage_client ARGS` with this interpreter."""
    return subprocess.run(
        [sys.executable, "-m", "afterimage_client", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


@pytest.fixture
def copy_frames(tmp_path):
    """Copies a fixture directory's EXRs into a fresh folder and returns it."""

    def copy(src, name="frames"):
        dst = tmp_path / name
        dst.mkdir()
        for f in sorted(os.listdir(src)):
            if f.endswith(".exr"):
                shutil.copy(os.path.join(src, f), dst / f)
        return dst

    return copy
