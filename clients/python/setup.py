"""Builds afterimage-client, generating its gRPC modules from the repository's proto.

afterimage_client/proto/afterimage_pb2.py, afterimage_pb2.pyi and afterimage_pb2_grpc.py are
not committed: every build (wheel, sdist-to-wheel, editable) writes them with grpcio-tools,
pinned in pyproject.toml's [build-system] so every install gets the same code, from
proto/afterimage/v1/afterimage.proto. In a checkout proto/ links to crates/client/proto (the
contract the server is built from); the sdist carries a copy (MANIFEST.in).
"""

import os
import re
import tempfile

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = os.path.dirname(os.path.abspath(__file__))
PROTO_ROOT = os.path.join(HERE, "proto")
PROTO = "afterimage/v1/afterimage.proto"  # relative to PROTO_ROOT, as protoc names it in the descriptor
GENERATED = ("afterimage_pb2.py", "afterimage_pb2.pyi", "afterimage_pb2_grpc.py")
PACKAGE_DIR = os.path.join("afterimage_client", "proto")


def generate(dest):
    """Writes the GENERATED modules into `dest` from PROTO_ROOT/PROTO."""
    proto = os.path.join(PROTO_ROOT, PROTO)
    if not os.path.isfile(proto):
        raise SystemExit(
            f"afterimage-client: no {proto}: build the package from a checkout of the afterimage "
            "repository (clients/python/proto links to crates/client/proto; pip >= 21.3 builds in place) "
            "or from its sdist, which carries the proto"
        )
    try:
        from grpc_tools import protoc
    except ImportError:
        raise SystemExit(
            "afterimage-client: the build needs grpcio-tools (pyproject.toml's [build-system] requires, "
            "which pip installs unless --no-build-isolation) to generate its gRPC modules"
        ) from None
    with tempfile.TemporaryDirectory() as tmp:
        argv = ["grpc_tools.protoc", f"-I{PROTO_ROOT}", f"--python_out={tmp}", f"--pyi_out={tmp}",
                f"--grpc_python_out={tmp}", PROTO]
        if protoc.main(argv) != 0:
            raise SystemExit(f"afterimage-client: grpc_tools.protoc failed on {proto}")
        os.makedirs(dest, exist_ok=True)
        for name in GENERATED:
            with open(os.path.join(tmp, "afterimage", "v1", name), encoding="utf-8", newline="") as f:
                code = f.read()
            # protoc imports the messages as the proto's path, a top-level package `afterimage.v1`;
            # in this package they are a sibling module.
            code = re.sub(r"^from afterimage\.v1 import (afterimage_pb2 as )", r"from . import \1", code, flags=re.M)
            with open(os.path.join(dest, name), "w", encoding="utf-8", newline="") as f:
                f.write(code)


class BuildPyWithProto(build_py):
    """build_py plus the generated modules: into the build directory, or, for an editable
    install (which imports the package from src/), next to the sources, where git ignores them."""

    def run(self):
        super().run()
        root = os.path.join(HERE, "src") if self.editable_mode else self.build_lib
        generate(os.path.join(root, PACKAGE_DIR))

    def get_outputs(self, include_bytecode=True):
        outputs = super().get_outputs(include_bytecode)
        if self.editable_mode:  # super() lists the keys of get_output_mapping
            return outputs
        return outputs + [os.path.join(self.build_lib, PACKAGE_DIR, n) for n in GENERATED]

    def get_output_mapping(self):
        mapping = super().get_output_mapping()
        if self.editable_mode:
            for n in GENERATED:
                mapping[os.path.join(self.build_lib, PACKAGE_DIR, n)] = os.path.join("src", PACKAGE_DIR, n)
        return mapping


setup(cmdclass={"build_py": BuildPyWithProto})
