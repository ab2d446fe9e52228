"""The one CDR codec of the project: the graph's message types as bytes, without rclpy.

The nodes' control path (one message at a time, raw subscriptions and serialized
publications), the recorder (stamps of what it writes), the bag writers and the bag reader
(K messages at a time, as numpy byte matrices) all serialise and deserialise here, against one
definition of each message layout (:mod:`.layout`); :mod:`.encode` and :mod:`.decode` hold
the per-message and the batch forms. No ROS import, so the analysis (no rclpy) uses it too.

Public API
----------
Type names
    :data:`TWIST_STAMPED`, :data:`WRENCH_STAMPED`, :data:`JOINT_STATE`, :data:`HEADER`,
    :data:`STRING`, :data:`CLOCK` (``pkg/msg/Name``), :data:`NS` (ns per s).
Layouts
    :class:`Layout`, :func:`message_layout` (built, cached), :func:`read_layout` (from bytes).
Per message
    :class:`StampedWriter`, :class:`JointStateWriter`, :func:`header_bytes`,
    :func:`clock_bytes`, :func:`encode_string`, :func:`encode_diagnostics`;
    :func:`read_stamped`, :class:`JointStateReader`,
    :func:`read_header`, :func:`read_frame`, :func:`read_stamp`, :func:`decode_string`.
Batches
    :func:`encode_rows` (K messages -> (K, R) uint8), :func:`encode_stamped`,
    :func:`encode_joint_state`, :func:`encode_clock` (lists of bytes); :func:`decode_batch`,
    :func:`decode_rows` -> :class:`Batch`.
rosbags
    :func:`typestore` (Jazzy types, for the bag writers), :func:`deserialize` (the fallback).
"""

from dcsms_ros.cdr.decode import (
    BATCH_TYPES,
    Batch,
    BatchReader,
    JointStateReader,
    decode_batch,
    decode_rows,
    decode_string,
    deserialize,
    read_frame,
    read_header,
    read_stamp,
    read_stamped,
    read_stamped_floats,
    typestore,
)
from dcsms_ros.cdr.encode import (
    DIAGNOSTIC_ARRAY,
    DiagnosticStatus,
    JointStateWriter,
    StampedWriter,
    clock_bytes,
    encode_clock,
    encode_diagnostics,
    encode_joint_state,
    encode_rows,
    encode_stamped,
    encode_string,
    header_bytes,
)
from dcsms_ros.cdr.layout import (
    CLOCK,
    HEADER,
    JOINT_FIELDS,
    JOINT_STATE,
    NS,
    STRING,
    SUPPORTED,
    TWIST_STAMPED,
    VECTOR_FIELD,
    WRENCH_STAMPED,
    Layout,
    message_layout,
    read_layout,
)

__all__ = [
    "BATCH_TYPES", "CLOCK", "DIAGNOSTIC_ARRAY", "HEADER", "JOINT_FIELDS", "JOINT_STATE", "NS",
    "STRING", "SUPPORTED", "TWIST_STAMPED", "VECTOR_FIELD", "WRENCH_STAMPED", "Batch",
    "BatchReader", "DiagnosticStatus", "JointStateReader", "JointStateWriter", "Layout",
    "StampedWriter", "clock_bytes", "decode_batch", "decode_rows", "decode_string",
    "deserialize", "encode_clock", "encode_diagnostics", "encode_joint_state", "encode_rows",
    "encode_stamped", "encode_string", "header_bytes", "message_layout", "read_frame",
    "read_header", "read_layout", "read_stamp", "read_stamped", "read_stamped_floats",
    "typestore",
]
