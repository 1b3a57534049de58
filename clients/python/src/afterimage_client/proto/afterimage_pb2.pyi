from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from typing import ClassVar as _ClassVar, Iterable as _Iterable, Mapping as _Mapping, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class SampleType(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    SAMPLE_TYPE_F32: _ClassVar[SampleType]
    SAMPLE_TYPE_F16: _ClassVar[SampleType]
    SAMPLE_TYPE_U32: _ClassVar[SampleType]

class Compression(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    COMPRESSION_NONE: _ClassVar[Compression]
    COMPRESSION_ZSTD: _ClassVar[Compression]
SAMPLE_TYPE_F32: SampleType
SAMPLE_TYPE_F16: SampleType
SAMPLE_TYPE_U32: SampleType
COMPRESSION_NONE: Compression
COMPRESSION_ZSTD: Compression

class OpenRegionRequest(_message.Message):
    __slots__ = ("session_id", "bytes")
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    BYTES_FIELD_NUMBER: _ClassVar[int]
    session_id: str
    bytes: int
    def __init__(self, session_id: _Optional[str] = ..., bytes: _Optional[int] = ...) -> None: ...

class Region(_message.Message):
    __slots__ = ("session_id", "path", "bytes")
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    PATH_FIELD_NUMBER: _ClassVar[int]
    BYTES_FIELD_NUMBER: _ClassVar[int]
    session_id: str
    path: str
    bytes: int
    def __init__(self, session_id: _Optional[str] = ..., path: _Optional[str] = ..., bytes: _Optional[int] = ...) -> None: ...

class SharedMemory(_message.Message):
    __slots__ = ("offset", "reply_offset")
    OFFSET_FIELD_NUMBER: _ClassVar[int]
    REPLY_OFFSET_FIELD_NUMBER: _ClassVar[int]
    offset: int
    reply_offset: int
    def __init__(self, offset: _Optional[int] = ..., reply_offset: _Optional[int] = ...) -> None: ...

class ListFiltersRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class ParamSpec(_message.Message):
    __slots__ = ("name", "kind", "default_json", "min", "max", "choices", "doc")
    NAME_FIELD_NUMBER: _ClassVar[int]
    KIND_FIELD_NUMBER: _ClassVar[int]
    DEFAULT_JSON_FIELD_NUMBER: _ClassVar[int]
    MIN_FIELD_NUMBER: _ClassVar[int]
    MAX_FIELD_NUMBER: _ClassVar[int]
    CHOICES_FIELD_NUMBER: _ClassVar[int]
    DOC_FIELD_NUMBER: _ClassVar[int]
    name: str
    kind: str
    default_json: str
    min: float
    max: float
    choices: _containers.RepeatedScalarFieldContainer[str]
    doc: str
    def __init__(self, name: _Optional[str] = ..., kind: _Optional[str] = ..., default_json: _Optional[str] = ..., min: _Optional[float] = ..., max: _Optional[float] = ..., choices: _Optional[_Iterable[str]] = ..., doc: _Optional[str] = ...) -> None: ...

class FilterInfo(_message.Message):
    __slots__ = ("name", "summary", "needs", "uses", "stages", "params", "state_bytes_per_pixel")
    NAME_FIELD_NUMBER: _ClassVar[int]
    SUMMARY_FIELD_NUMBER: _ClassVar[int]
    NEEDS_FIELD_NUMBER: _ClassVar[int]
    USES_FIELD_NUMBER: _ClassVar[int]
    STAGES_FIELD_NUMBER: _ClassVar[int]
    PARAMS_FIELD_NUMBER: _ClassVar[int]
    STATE_BYTES_PER_PIXEL_FIELD_NUMBER: _ClassVar[int]
    name: str
    summary: str
    needs: _containers.RepeatedScalarFieldContainer[str]
    uses: _containers.RepeatedScalarFieldContainer[str]
    stages: _containers.RepeatedScalarFieldContainer[str]
    params: _containers.RepeatedCompositeFieldContainer[ParamSpec]
    state_bytes_per_pixel: int
    def __init__(self, name: _Optional[str] = ..., summary: _Optional[str] = ..., needs: _Optional[_Iterable[str]] = ..., uses: _Optional[_Iterable[str]] = ..., stages: _Optional[_Iterable[str]] = ..., params: _Optional[_Iterable[_Union[ParamSpec, _Mapping]]] = ..., state_bytes_per_pixel: _Optional[int] = ...) -> None: ...

class ListFiltersResponse(_message.Message):
    __slots__ = ("filters",)
    FILTERS_FIELD_NUMBER: _ClassVar[int]
    filters: _containers.RepeatedCompositeFieldContainer[FilterInfo]
    def __init__(self, filters: _Optional[_Iterable[_Union[FilterInfo, _Mapping]]] = ...) -> None: ...

class CreateSessionRequest(_message.Message):
    __slots__ = ("filter", "params", "width", "height", "motion", "channels", "backend")
    class ParamsEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: str
        def __init__(self, key: _Optional[str] = ..., value: _Optional[str] = ...) -> None: ...
    FILTER_FIELD_NUMBER: _ClassVar[int]
    PARAMS_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    MOTION_FIELD_NUMBER: _ClassVar[int]
    CHANNELS_FIELD_NUMBER: _ClassVar[int]
    BACKEND_FIELD_NUMBER: _ClassVar[int]
    filter: str
    params: _containers.ScalarMap[str, str]
    width: int
    height: int
    motion: str
    channels: _containers.RepeatedScalarFieldContainer[str]
    backend: str
    def __init__(self, filter: _Optional[str] = ..., params: _Optional[_Mapping[str, str]] = ..., width: _Optional[int] = ..., height: _Optional[int] = ..., motion: _Optional[str] = ..., channels: _Optional[_Iterable[str]] = ..., backend: _Optional[str] = ...) -> None: ...

class Session(_message.Message):
    __slots__ = ("id", "filter", "params_json", "width", "height", "motion", "channels", "needs", "uses", "state_bytes", "frames", "idle_seconds", "max_chunk_bytes", "lookahead", "backend")
    ID_FIELD_NUMBER: _ClassVar[int]
    FILTER_FIELD_NUMBER: _ClassVar[int]
    PARAMS_JSON_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    MOTION_FIELD_NUMBER: _ClassVar[int]
    CHANNELS_FIELD_NUMBER: _ClassVar[int]
    NEEDS_FIELD_NUMBER: _ClassVar[int]
    USES_FIELD_NUMBER: _ClassVar[int]
    STATE_BYTES_FIELD_NUMBER: _ClassVar[int]
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    IDLE_SECONDS_FIELD_NUMBER: _ClassVar[int]
    MAX_CHUNK_BYTES_FIELD_NUMBER: _ClassVar[int]
    LOOKAHEAD_FIELD_NUMBER: _ClassVar[int]
    BACKEND_FIELD_NUMBER: _ClassVar[int]
    id: str
    filter: str
    params_json: str
    width: int
    height: int
    motion: str
    channels: _containers.RepeatedScalarFieldContainer[str]
    needs: _containers.RepeatedScalarFieldContainer[str]
    uses: _containers.RepeatedScalarFieldContainer[str]
    state_bytes: int
    frames: int
    idle_seconds: float
    max_chunk_bytes: int
    lookahead: int
    backend: str
    def __init__(self, id: _Optional[str] = ..., filter: _Optional[str] = ..., params_json: _Optional[str] = ..., width: _Optional[int] = ..., height: _Optional[int] = ..., motion: _Optional[str] = ..., channels: _Optional[_Iterable[str]] = ..., needs: _Optional[_Iterable[str]] = ..., uses: _Optional[_Iterable[str]] = ..., state_bytes: _Optional[int] = ..., frames: _Optional[int] = ..., idle_seconds: _Optional[float] = ..., max_chunk_bytes: _Optional[int] = ..., lookahead: _Optional[int] = ..., backend: _Optional[str] = ...) -> None: ...

class GetSessionRequest(_message.Message):
    __slots__ = ("id",)
    ID_FIELD_NUMBER: _ClassVar[int]
    id: str
    def __init__(self, id: _Optional[str] = ...) -> None: ...

class CloseSessionRequest(_message.Message):
    __slots__ = ("id",)
    ID_FIELD_NUMBER: _ClassVar[int]
    id: str
    def __init__(self, id: _Optional[str] = ...) -> None: ...

class CloseSessionResponse(_message.Message):
    __slots__ = ("frames",)
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    frames: int
    def __init__(self, frames: _Optional[int] = ...) -> None: ...

class ChannelHeader(_message.Message):
    __slots__ = ("name", "sample", "compression", "byte_length")
    NAME_FIELD_NUMBER: _ClassVar[int]
    SAMPLE_FIELD_NUMBER: _ClassVar[int]
    COMPRESSION_FIELD_NUMBER: _ClassVar[int]
    BYTE_LENGTH_FIELD_NUMBER: _ClassVar[int]
    name: str
    sample: SampleType
    compression: Compression
    byte_length: int
    def __init__(self, name: _Optional[str] = ..., sample: _Optional[_Union[SampleType, str]] = ..., compression: _Optional[_Union[Compression, str]] = ..., byte_length: _Optional[int] = ...) -> None: ...

class FrameHeader(_message.Message):
    __slots__ = ("session_id", "index", "reset", "jitter_x", "jitter_y", "channels", "reply_sample", "reply_compression", "shading_factor", "shading_phase_x", "shading_phase_y", "shared_memory")
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    INDEX_FIELD_NUMBER: _ClassVar[int]
    RESET_FIELD_NUMBER: _ClassVar[int]
    JITTER_X_FIELD_NUMBER: _ClassVar[int]
    JITTER_Y_FIELD_NUMBER: _ClassVar[int]
    CHANNELS_FIELD_NUMBER: _ClassVar[int]
    REPLY_SAMPLE_FIELD_NUMBER: _ClassVar[int]
    REPLY_COMPRESSION_FIELD_NUMBER: _ClassVar[int]
    SHADING_FACTOR_FIELD_NUMBER: _ClassVar[int]
    SHADING_PHASE_X_FIELD_NUMBER: _ClassVar[int]
    SHADING_PHASE_Y_FIELD_NUMBER: _ClassVar[int]
    SHARED_MEMORY_FIELD_NUMBER: _ClassVar[int]
    session_id: str
    index: int
    reset: bool
    jitter_x: float
    jitter_y: float
    channels: _containers.RepeatedCompositeFieldContainer[ChannelHeader]
    reply_sample: SampleType
    reply_compression: Compression
    shading_factor: int
    shading_phase_x: int
    shading_phase_y: int
    shared_memory: SharedMemory
    def __init__(self, session_id: _Optional[str] = ..., index: _Optional[int] = ..., reset: bool = ..., jitter_x: _Optional[float] = ..., jitter_y: _Optional[float] = ..., channels: _Optional[_Iterable[_Union[ChannelHeader, _Mapping]]] = ..., reply_sample: _Optional[_Union[SampleType, str]] = ..., reply_compression: _Optional[_Union[Compression, str]] = ..., shading_factor: _Optional[int] = ..., shading_phase_x: _Optional[int] = ..., shading_phase_y: _Optional[int] = ..., shared_memory: _Optional[_Union[SharedMemory, _Mapping]] = ...) -> None: ...

class DataChunk(_message.Message):
    __slots__ = ("data",)
    DATA_FIELD_NUMBER: _ClassVar[int]
    data: bytes
    def __init__(self, data: _Optional[bytes] = ...) -> None: ...

class FrameChunk(_message.Message):
    __slots__ = ("header", "data")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    DATA_FIELD_NUMBER: _ClassVar[int]
    header: FrameHeader
    data: DataChunk
    def __init__(self, header: _Optional[_Union[FrameHeader, _Mapping]] = ..., data: _Optional[_Union[DataChunk, _Mapping]] = ...) -> None: ...

class StageTime(_message.Message):
    __slots__ = ("name", "ms", "skipped")
    NAME_FIELD_NUMBER: _ClassVar[int]
    MS_FIELD_NUMBER: _ClassVar[int]
    SKIPPED_FIELD_NUMBER: _ClassVar[int]
    name: str
    ms: float
    skipped: str
    def __init__(self, name: _Optional[str] = ..., ms: _Optional[float] = ..., skipped: _Optional[str] = ...) -> None: ...

class FrameReport(_message.Message):
    __slots__ = ("index", "total_ms", "stages", "history_reset", "history_rejected", "history_clipped", "non_finite_input", "negative_input", "state_bytes", "psnr", "ssim", "record_json", "server_ms")
    INDEX_FIELD_NUMBER: _ClassVar[int]
    TOTAL_MS_FIELD_NUMBER: _ClassVar[int]
    STAGES_FIELD_NUMBER: _ClassVar[int]
    HISTORY_RESET_FIELD_NUMBER: _ClassVar[int]
    HISTORY_REJECTED_FIELD_NUMBER: _ClassVar[int]
    HISTORY_CLIPPED_FIELD_NUMBER: _ClassVar[int]
    NON_FINITE_INPUT_FIELD_NUMBER: _ClassVar[int]
    NEGATIVE_INPUT_FIELD_NUMBER: _ClassVar[int]
    STATE_BYTES_FIELD_NUMBER: _ClassVar[int]
    PSNR_FIELD_NUMBER: _ClassVar[int]
    SSIM_FIELD_NUMBER: _ClassVar[int]
    RECORD_JSON_FIELD_NUMBER: _ClassVar[int]
    SERVER_MS_FIELD_NUMBER: _ClassVar[int]
    index: int
    total_ms: float
    stages: _containers.RepeatedCompositeFieldContainer[StageTime]
    history_reset: int
    history_rejected: int
    history_clipped: int
    non_finite_input: int
    negative_input: int
    state_bytes: int
    psnr: float
    ssim: float
    record_json: str
    server_ms: float
    def __init__(self, index: _Optional[int] = ..., total_ms: _Optional[float] = ..., stages: _Optional[_Iterable[_Union[StageTime, _Mapping]]] = ..., history_reset: _Optional[int] = ..., history_rejected: _Optional[int] = ..., history_clipped: _Optional[int] = ..., non_finite_input: _Optional[int] = ..., negative_input: _Optional[int] = ..., state_bytes: _Optional[int] = ..., psnr: _Optional[float] = ..., ssim: _Optional[float] = ..., record_json: _Optional[str] = ..., server_ms: _Optional[float] = ...) -> None: ...

class FilteredHeader(_message.Message):
    __slots__ = ("session_id", "index", "width", "height", "color", "report", "shared_memory")
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    INDEX_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    COLOR_FIELD_NUMBER: _ClassVar[int]
    REPORT_FIELD_NUMBER: _ClassVar[int]
    SHARED_MEMORY_FIELD_NUMBER: _ClassVar[int]
    session_id: str
    index: int
    width: int
    height: int
    color: ChannelHeader
    report: FrameReport
    shared_memory: SharedMemory
    def __init__(self, session_id: _Optional[str] = ..., index: _Optional[int] = ..., width: _Optional[int] = ..., height: _Optional[int] = ..., color: _Optional[_Union[ChannelHeader, _Mapping]] = ..., report: _Optional[_Union[FrameReport, _Mapping]] = ..., shared_memory: _Optional[_Union[SharedMemory, _Mapping]] = ...) -> None: ...

class FilteredChunk(_message.Message):
    __slots__ = ("header", "data")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    DATA_FIELD_NUMBER: _ClassVar[int]
    header: FilteredHeader
    data: DataChunk
    def __init__(self, header: _Optional[_Union[FilteredHeader, _Mapping]] = ..., data: _Optional[_Union[DataChunk, _Mapping]] = ...) -> None: ...
