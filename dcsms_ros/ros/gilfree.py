"""The few rcl calls of the executor's thread that are long enough to make the real-time thread
of its process wait, made through :mod:`ctypes` with the GIL released.

rclpy holds the GIL through every call into rcl. Most take microseconds, but in the composed
real-time graph two took hundreds: publishing a ``/diagnostics`` report (serialising it
~185 us of CPU, the DDS write ~250 us; six reports a second) and the recorder's discovery,
``get_topic_names_and_types`` (~440 us; twice a second). The driver thread, woken at its
deadline on the same core, preempts the executor's thread at once but cannot run Python until
the call returns: 102 of its wake-ups in one 20 s run ended 0.3-0.9 ms late that way, while the
executor's thread was running (docs/performance.md, "The executor's C calls"). Later, in 2
runs, 5 wake-ups 0.30-0.39 ms late found the executor's thread just back from rclpy's
``service_is_ready`` (mode_switch's check of the controllers' enable services, 6 a second),
none in 9 runs with it here. Through
:mod:`ctypes` the same rcl functions run without the GIL, so the driver runs Python as soon
as it is woken. The caller serialises a message in Python (which yields the GIL every switch
interval) and publishes the bytes.

rclpy has loaded ``librcl`` before any node exists; this module opens the same library. Where
it cannot (:data:`AVAILABLE` false), each function makes rclpy's own call instead.
"""

from __future__ import annotations

import ctypes
from typing import Any

from rclpy.client import Client
from rclpy.node import Node
from rclpy.publisher import Publisher

#: rcl_ret_t of success
_OK = 0


class _Allocator(ctypes.Structure):
    _fields_ = [("allocate", ctypes.c_void_p), ("deallocate", ctypes.c_void_p),
                ("reallocate", ctypes.c_void_p), ("zero_allocate", ctypes.c_void_p),
                ("state", ctypes.c_void_p)]


class _Bytes(ctypes.Structure):  # rcutils_uint8_array_t, rcl_serialized_message_t
    _fields_ = [("buffer", ctypes.c_void_p), ("buffer_length", ctypes.c_size_t),
                ("buffer_capacity", ctypes.c_size_t), ("allocator", _Allocator)]


class _Strings(ctypes.Structure):  # rcutils_string_array_t
    _fields_ = [("size", ctypes.c_size_t), ("data", ctypes.POINTER(ctypes.c_char_p)),
                ("allocator", _Allocator)]


class _NamesAndTypes(ctypes.Structure):  # rcl_names_and_types_t
    _fields_ = [("names", _Strings), ("types", ctypes.POINTER(_Strings))]


class _ErrorString(ctypes.Structure):  # rcutils_error_string_t
    _fields_ = [("str", ctypes.c_char * 1024)]


def _load() -> tuple[Any, Any] | None:
    try:
        rcl, rcutils = ctypes.CDLL("librcl.so"), ctypes.CDLL("librcutils.so")
    except OSError:
        return None
    rcl.rcl_publish_serialized_message.argtypes = [ctypes.c_void_p, ctypes.POINTER(_Bytes),
                                                   ctypes.c_void_p]
    rcl.rcl_get_topic_names_and_types.argtypes = [
        ctypes.c_void_p, ctypes.POINTER(_Allocator), ctypes.c_bool,
        ctypes.POINTER(_NamesAndTypes)]
    rcl.rcl_names_and_types_fini.argtypes = [ctypes.POINTER(_NamesAndTypes)]
    rcl.rcl_count_publishers.argtypes = [ctypes.c_void_p, ctypes.c_char_p,
                                         ctypes.POINTER(ctypes.c_size_t)]
    rcl.rcl_service_server_is_available.argtypes = [ctypes.c_void_p, ctypes.c_void_p,
                                                    ctypes.POINTER(ctypes.c_bool)]
    for f in (rcl.rcl_publish_serialized_message, rcl.rcl_get_topic_names_and_types,
              rcl.rcl_names_and_types_fini, rcl.rcl_count_publishers,
              rcl.rcl_service_server_is_available):
        f.restype = ctypes.c_int
    rcutils.rcutils_get_default_allocator.restype = _Allocator
    rcutils.rcutils_get_error_string.restype = _ErrorString
    return rcl, rcutils


_LIBS = _load()
#: Whether the calls below release the GIL (librcl could be opened).
AVAILABLE = _LIBS is not None


def _check(ret: int, what: str) -> None:
    if ret != _OK:
        assert _LIBS is not None
        rcutils = _LIBS[1]
        text = rcutils.rcutils_get_error_string().str.decode(errors="replace")
        rcutils.rcutils_reset_error()
        raise RuntimeError(f"{what} failed ({ret}): {text}")


def publish_bytes(pub: Publisher, data: bytes) -> None:
    """Publish the serialised message ``data`` (CDR with its encapsulation header) on ``pub``,
    as ``pub.publish(data)`` does, with the GIL released during the write."""
    if _LIBS is None:
        pub.publish(data)
        return
    msg = _Bytes(ctypes.cast(ctypes.c_char_p(data), ctypes.c_void_p), len(data), len(data))
    with pub.handle:  # as rclpy's publish: the publisher is not destroyed meanwhile
        ret = _LIBS[0].rcl_publish_serialized_message(pub.handle.pointer, ctypes.byref(msg),
                                                      None)
    _check(ret, f"publishing on {pub.topic_name}")


def topic_names_and_types(node: Node) -> list[tuple[str, list[str]]]:
    """The topics of the graph and their types, as ``node.get_topic_names_and_types()``."""
    if _LIBS is None:
        return node.get_topic_names_and_types()
    rcl, rcutils = _LIBS
    allocator = rcutils.rcutils_get_default_allocator()
    out = _NamesAndTypes()
    with node.handle:
        ret = rcl.rcl_get_topic_names_and_types(node.handle.pointer, ctypes.byref(allocator),
                                                False, ctypes.byref(out))
    _check(ret, "listing the graph's topics")
    try:
        return [(out.names.data[i].decode(),
                 [out.types[i].data[j].decode() for j in range(out.types[i].size)])
                for i in range(out.names.size)]
    finally:
        _check(rcl.rcl_names_and_types_fini(ctypes.byref(out)), "freeing the topic list")


def count_publishers(node: Node, topic: str) -> int:
    """Publishers of ``topic`` (its fully qualified name, as the graph lists it) in ``node``'s
    graph view, as ``node.count_publishers(topic)``."""
    if _LIBS is None:
        return node.count_publishers(topic)
    count = ctypes.c_size_t()
    with node.handle:
        ret = _LIBS[0].rcl_count_publishers(node.handle.pointer, topic.encode(),
                                            ctypes.byref(count))
    _check(ret, f"counting the publishers of {topic}")
    return count.value


def service_is_ready(node: Node, client: Client) -> bool:
    """Whether ``client``'s service has a server in ``node``'s graph view (``client`` made by
    ``node``), as ``client.service_is_ready()``."""
    if _LIBS is None:
        return client.service_is_ready()
    ready = ctypes.c_bool()
    with node.handle, client.handle:
        ret = _LIBS[0].rcl_service_server_is_available(
            node.handle.pointer, client.handle.pointer, ctypes.byref(ready))
    _check(ret, f"checking the server of {client.srv_name}")
    return ready.value


__all__ = ["AVAILABLE", "count_publishers", "publish_bytes", "service_is_ready",
           "topic_names_and_types"]
