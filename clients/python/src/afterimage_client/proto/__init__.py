"""Generated from crates/client/proto/afterimage/v1/afterimage.proto by tools/regen_proto.sh (do not edit
the afterimage_pb2* modules by hand; regenerate them)."""

from . import afterimage_pb2, afterimage_pb2_grpc

__all__ = ["afterimage_pb2", "afterimage_pb2_grpc"]
