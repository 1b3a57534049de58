"""The afterimage_pb2* modules are generated from crates/client/proto/afterimage/v1/afterimage.proto
when the package is built (clients/python/setup.py); they are not in the repository."""

from importlib.util import find_spec

if find_spec(f"{__name__}.afterimage_pb2") is None:
    # The source tree imported as is (PYTHONPATH=src), or an editable install whose generated
    # files were deleted, has none: say how to get them.
    raise ImportError(
        f"{__name__}.afterimage_pb2 is generated when the package is built: install afterimage-client "
        "(`pip install ./clients/python`, or `pip install -e ./clients/python` in a checkout, again "
        "after the proto changes) instead of importing it from its source directory"
    )

from . import afterimage_pb2, afterimage_pb2_grpc  # noqa: E402

__all__ = ["afterimage_pb2", "afterimage_pb2_grpc"]
