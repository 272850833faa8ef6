"""The server side of CRTP, the Crazyflie's packet protocol, as far as cflib's connection and our bridge need it.

A CRTP packet is one header byte (port in bits 7-4, channel in bits 1-0) and up to 30 data
bytes; over cflib's UDP driver each datagram carries exactly one packet. This module holds
the port/channel/command numbers (from the public Crazyflie firmware and cflib protocol
documentation), the variable tables a virtual Crazyflie offers, and small codecs. Table
of contents (TOC) replies use protocol version 2 (16-bit ids) and carry a CRC so that
cflib's TOC cache works.
"""

from __future__ import annotations

import dataclasses
import struct
import zlib

MAX_DATA = 30  # bytes of payload per packet

# ports
CONSOLE, PARAM, COMMANDER, MEM, LOG, LOCALIZATION, GENERIC_COMMANDER, HIGH_LEVEL, SUPERVISOR, PLATFORM, LINK = (
    0, 2, 3, 4, 5, 6, 7, 8, 9, 13, 15,
)

# channels and commands of the TOC-based services (param and log share the TOC channel)
TOC_CHANNEL = 0
TOC_ITEM_V2, TOC_INFO_V2 = 2, 3
PARAM_READ, PARAM_WRITE, PARAM_MISC = 1, 2, 3
LOG_SETTINGS, LOG_DATA = 1, 2
LOG_CREATE, LOG_APPEND, LOG_DELETE, LOG_START, LOG_STOP, LOG_RESET, LOG_CREATE_V2, LOG_APPEND_V2 = 0, 1, 2, 3, 4, 5, 6, 7
MAX_LOG_BLOCK_BYTES = 26  # 30 minus block id and 3-byte timestamp

# link control: channel 0 echo, channel 1 "source" (identifies a Crazyflie)
LINK_ECHO, LINK_SOURCE = 0, 1
SOURCE_MAGIC = b"Bitcraze Crazyflie"
# platform: channel 0 commands, channel 1 version queries
PLATFORM_COMMAND, PLATFORM_VERSION = 0, 1
PLATFORM_ARM, PLATFORM_RECOVER = 1, 2
VERSION_PROTOCOL = 0
PROTOCOL_VERSION = 12  # cflib 0.1.34 uses the supervisor port from 12 on

# generic commander (channel 0 setpoints, channel 1 meta commands)
SETPOINT_STOP, VELOCITY_WORLD_LEGACY, ZDISTANCE_LEGACY, HOVER_LEGACY = 0, 1, 2, 5
POSITION, VELOCITY_WORLD, ZDISTANCE, HOVER = 7, 8, 9, 10
META_NOTIFY_SETPOINT_STOP = 0
# high-level commander
HL_SET_GROUP_MASK, HL_STOP, HL_GO_TO, HL_TAKEOFF_2, HL_LAND_2, HL_GO_TO_2 = 0, 3, 4, 7, 8, 12
# supervisor (channel 0 info, channel 1 commands; replies set bit 7 of the command)
SUPERVISOR_INFO, SUPERVISOR_COMMAND = 0, 1
SUP_ARM, SUP_RECOVER, SUP_EMERGENCY_STOP, SUP_EMERGENCY_WATCHDOG, SUP_GET_STATE = 0x01, 0x02, 0x03, 0x04, 0x0C
# localization generic channel
LOC_GENERIC = 1
LOC_EMERGENCY_STOP, LOC_EMERGENCY_WATCHDOG = 3, 4
# memory: we report no memories
MEM_INFO, MEM_INFO_COUNT = 0, 1

# value types: (log type id, param type id, struct code)
TYPES = {
    "uint8_t": (0x01, 0x08, "B"),
    "uint16_t": (0x02, 0x09, "H"),
    "uint32_t": (0x03, 0x0A, "I"),
    "int8_t": (0x04, 0x00, "b"),
    "int16_t": (0x05, 0x01, "h"),
    "int32_t": (0x06, 0x02, "i"),
    "float": (0x07, 0x06, "f"),
    "FP16": (0x08, 0x05, "e"),
}
LOG_TYPE_CODE = {v[0]: v[2] for v in TYPES.values()}
PARAM_READ_ONLY = 0x40


def header(port: int, channel: int) -> int:
    """The CRTP header byte (bits 3-2 set, as every Crazyflie sends them)."""
    return ((port & 0x0F) << 4) | 0x0C | (channel & 0x03)


def split_header(h: int) -> tuple[int, int]:
    """(port, channel) of a header byte."""
    return (h >> 4) & 0x0F, h & 0x03


@dataclasses.dataclass(frozen=True)
class Variable:
    """One TOC entry: 'group.name', its C type, and for params whether it is read-only."""

    name: str
    ctype: str
    read_only: bool = False

    @property
    def group_and_name(self) -> bytes:
        group, name = self.name.split(".")
        return group.encode() + b"\0" + name.encode() + b"\0"


class Toc:
    """An ordered table of variables with a CRC over its content; ids are positions."""

    def __init__(self, variables: list[Variable], kind: str):
        self.variables = list(variables)
        self.kind = kind  # "log" or "param"
        self.ids = {v.name: i for i, v in enumerate(self.variables)}
        for v in self.variables:
            if 4 + len(v.group_and_name) > MAX_DATA:
                raise ValueError(f"{kind} TOC: name '{v.name}' is too long for one packet")
        self.crc = zlib.crc32(b"".join(self._type_byte(v).to_bytes(1, "little") + v.group_and_name for v in self.variables))

    def _type_byte(self, v: Variable) -> int:
        log_id, param_id, _ = TYPES[v.ctype]
        if self.kind == "log":
            return log_id
        return param_id | (PARAM_READ_ONLY if v.read_only else 0)

    def info_reply(self) -> bytes:
        return struct.pack("<BHI", TOC_INFO_V2, len(self.variables), self.crc)

    def item_reply(self, ident: int) -> bytes | None:
        if not 0 <= ident < len(self.variables):
            return None
        v = self.variables[ident]
        return struct.pack("<BHB", TOC_ITEM_V2, ident, self._type_byte(v)) + v.group_and_name


#: what a virtual Crazyflie can log; units as in the firmware (m, m/s, deg, V)
LOG_VARIABLES = [
    Variable("stateEstimate.x", "float"),
    Variable("stateEstimate.y", "float"),
    Variable("stateEstimate.z", "float"),
    Variable("stateEstimate.vx", "float"),
    Variable("stateEstimate.vy", "float"),
    Variable("stateEstimate.vz", "float"),
    Variable("stateEstimate.roll", "float"),
    Variable("stateEstimate.pitch", "float"),
    Variable("stateEstimate.yaw", "float"),
    Variable("kalman.varPX", "float"),
    Variable("kalman.varPY", "float"),
    Variable("kalman.varPZ", "float"),
    Variable("pm.vbat", "float"),
    Variable("pm.batteryLevel", "uint8_t"),
    Variable("pm.state", "int8_t"),
    Variable("supervisor.info", "uint16_t"),
    Variable("motor.m1", "uint16_t"),
    Variable("motor.m2", "uint16_t"),
    Variable("motor.m3", "uint16_t"),
    Variable("motor.m4", "uint16_t"),
]

#: what a virtual Crazyflie lets you read or set
PARAM_VARIABLES = [
    Variable("deck.bcFlow2", "uint8_t", read_only=True),
    Variable("deck.bcLighthouse4", "uint8_t", read_only=True),
    Variable("deck.bcLoco", "uint8_t", read_only=True),
    Variable("kalman.resetEstimation", "uint8_t"),
    Variable("stabilizer.estimator", "uint8_t"),
    Variable("stabilizer.controller", "uint8_t"),
    Variable("commander.enHighLevel", "uint8_t"),
    Variable("pm.lowVoltage", "float"),
    Variable("posCtlPid.rLimit", "float"),  # deg: the velocity loop's roll limit
    Variable("posCtlPid.pLimit", "float"),  # deg: and its pitch limit
]

DECK_PARAMS = {"flow": "deck.bcFlow2", "lighthouse": "deck.bcLighthouse4", "loco": "deck.bcLoco"}


def pack_value(ctype_code: str, value: float) -> bytes:
    """One value in a struct code ('f', 'B' ...), rounded and saturated for integer types."""
    if ctype_code in "fe":
        return struct.pack("<" + ctype_code, float(value))
    lo, hi = {"B": (0, 255), "H": (0, 65535), "I": (0, 2**32 - 1), "b": (-128, 127), "h": (-32768, 32767), "i": (-(2**31), 2**31 - 1)}[ctype_code]
    return struct.pack("<" + ctype_code, int(min(max(round(value), lo), hi)))
