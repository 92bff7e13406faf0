"""ROS 2 message types for DDS: IDL types with ROS 2's names, made from ``rosbags``' message definitions, and the
CDR (de)serialisation of the messages.

The DDS topic of a ROS message type needs an IDL type with the ROS 2 type name and the same members in the same
order and types as ``rosidl`` generates them (msg ``byte`` is IDL ``octet``, ``char`` is ``uint8``, ``T[]`` is
``sequence<T>``, ``T[N]`` an array, ``T[<=N]`` a bounded sequence, ``string<=N`` a bounded string; an empty message
gets rosidl's ``uint8 structure_needs_at_least_one_member``). :func:`idl_type` builds them from a ``rosbags``
typestore (the ROS 2 Humble definitions, those a bag carries, and PX4's ``px4_msgs/msg/VehicleOdometry``), so no
definition is written twice.

The messages themselves are ``rosbags`` message objects, serialized with ``rosbags`` (:func:`encode`), the bytes
ROS 2 bags hold, and read back with it (:func:`decode`); a sample in XCDR2 (a non-ROS publisher's default) is
converted to XCDR1 by the IDL type first.
"""

from __future__ import annotations

import functools
from typing import Any

from ..errors import DatasetError
from .dds import CDR_LE, dds_type

#: PX4's odometry message (``px4_msgs/msg/VehicleOdometry``, PX4 v1.14 and later; the uXRCE-DDS bridge's
#: ``/fmu/out/vehicle_odometry``): timestamps in microseconds, position in metres and ``q`` (w, x, y, z) from the FRD
#: body to the NED (or FRD) world frame, NaN where invalid.
PX4_VEHICLE_ODOMETRY = """
uint64 timestamp
uint64 timestamp_sample
uint8 POSE_FRAME_UNKNOWN = 0
uint8 POSE_FRAME_NED = 1
uint8 POSE_FRAME_FRD = 2
uint8 pose_frame
float32[3] position
float32[4] q
uint8 velocity_frame
float32[3] velocity
float32[3] angular_velocity
float32[3] position_variance
float32[3] orientation_variance
float32[3] velocity_variance
uint8 reset_counter
int8 quality
"""


@functools.lru_cache(maxsize=1)
def typestore():
    """The ``rosbags`` typestore of the messages used here: ROS 2 Humble's plus PX4's VehicleOdometry."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    ts.register(get_types_from_msg(PX4_VEHICLE_ODOMETRY, "px4_msgs/msg/VehicleOdometry"))
    return ts


def _base_types() -> dict[str, Any]:
    import cyclonedds.idl.types as t

    return {
        "bool": bool,
        "byte": t.byte,
        "octet": t.byte,
        "char": t.uint8,
        "int8": t.int8,
        "uint8": t.uint8,
        "int16": t.int16,
        "uint16": t.uint16,
        "int32": t.int32,
        "uint32": t.uint32,
        "int64": t.int64,
        "uint64": t.uint64,
        "float32": t.float32,
        "float64": t.float64,
        "string": str,
    }


_CACHE: dict[tuple[int, str], type] = {}


def idl_type(msgtype: str, store=None) -> type:
    """The IDL struct class of ROS message type ``msgtype`` (``pkg/msg/Type``) as ``rmw_cyclonedds`` names and lays
    it out, from the definitions of ``store`` (a rosbags typestore; default :func:`typestore`)."""
    import cyclonedds.idl.types as t
    from cyclonedds.idl import make_idl_struct

    store = typestore() if store is None else store
    key = (id(store), msgtype)
    if key in _CACHE:
        return _CACHE[key]
    if msgtype not in store.fielddefs:
        raise DatasetError(f"message type {msgtype} has no definition here")
    base = _base_types()

    def member(node) -> Any:
        kind, arg = node
        kind = getattr(kind, "name", kind)
        if kind == "BASE":
            name, bound = arg
            if name not in base:
                raise DatasetError(f"{msgtype}: field type {name} cannot be mapped to DDS")
            return t.bounded_str[bound] if name == "string" and bound else base[name]
        if kind == "NAME":
            return idl_type(arg, store)
        if kind == "ARRAY":
            return t.array[member(arg[0]), arg[1]]
        if kind == "SEQUENCE":
            return t.sequence[member(arg[0]), arg[1]] if arg[1] else t.sequence[member(arg[0])]
        raise DatasetError(f"{msgtype}: field kind {kind} cannot be mapped to DDS")

    _, fields = store.fielddefs[msgtype]
    members = {n: member(f) for n, f in fields} or {"structure_needs_at_least_one_member": t.uint8}
    name = msgtype.split("/")[-1]
    cls = make_idl_struct(f"{name}_", dds_type(msgtype), members)
    _CACHE[key] = cls
    return cls


def encode(msg: Any, store=None) -> memoryview:
    """The XCDR1 little-endian bytes of a rosbags message (encapsulation header first), as ROS 2 sends them."""
    store = typestore() if store is None else store
    return store.serialize_cdr(msg, msg.__msgtype__)


def decode(data: bytes, msgtype: str, store=None) -> Any:
    """The rosbags message of a sample's bytes (XCDR1 as ROS 2 sends; XCDR2 converted by the IDL type); a
    DatasetError when they do not hold a ``msgtype``."""
    store = typestore() if store is None else store
    head = bytes(data[:4])
    try:
        if head[:2] not in (CDR_LE[:2], b"\x00\x00"):  # XCDR2 (plain, delimited or parameter list): re-encode
            cls = idl_type(msgtype, store)
            data = cls.deserialize(bytes(data)).serialize(use_version_2=False)
        return store.deserialize_cdr(data, msgtype)
    except Exception as e:  # rosbags and the IDL machinery raise their own types for malformed bytes
        text = str(e).strip().splitlines()
        raise DatasetError(
            f"cannot decode a {msgtype} sample of {len(data)} bytes ({text[0][:200] if text else type(e).__name__})"
        ) from None


__all__ = ["PX4_VEHICLE_ODOMETRY", "decode", "encode", "idl_type", "typestore"]
