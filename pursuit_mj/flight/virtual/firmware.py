"""One virtual Crazyflie's protocol side: it answers cflib's packets like the firmware does.

`VirtualFirmware.handle(t, datagram)` returns the reply datagrams; `due_logs(t)` the log
packets whose period has come. Setpoints go into the shared `Commander` registers (row
`index`); the values it logs come from `read(name)` (the fleet's sensors, one row per
drone). Everything runs on the fleet's thread; nothing here blocks.
"""

from __future__ import annotations

import dataclasses
import struct
from typing import Callable

import numpy as np

from . import commander as cmd
from . import protocol as p

LOG_TOC = p.Toc(p.LOG_VARIABLES, "log")
PARAM_TOC = p.Toc(p.PARAM_VARIABLES, "param")
FIRMWARE_TILT_LIMIT = 20.0  # deg: PID_VEL_ROLL_MAX and PID_VEL_PITCH_MAX of the firmware's platform_defaults_cf2.h
_STATE_VARIABLES = {LOG_TOC.ids[v.name] for v in p.LOG_VARIABLES if v.name.startswith("stateEstimate.")}


@dataclasses.dataclass
class LogBlock:
    """A log configuration cflib created: variables (toc id, fetch struct code), period (s)."""

    variables: list[tuple[int, str]]
    period: float = 0.1
    running: bool = False
    next_due: float = 0.0

    @property
    def size(self) -> int:
        return sum(struct.calcsize("<" + code) for _, code in self.variables)


@dataclasses.dataclass
class Received:
    """A setpoint or command as the drone received it: time (s, virtual clock), kind, values."""

    t: float
    kind: str
    values: tuple[float, ...]


class VirtualFirmware:
    """Protocol handler of drone `index` (see module docstring).

    position(index) -> (3,) m: the drone's estimate now (for HLC plans from the current
    spot); reset_estimator(index, t): what writing kalman.resetEstimation=1 does.
    """

    def __init__(self, index: int, commander: cmd.Commander, read: Callable[[str], float],
                 position: Callable[[int], np.ndarray], reset_estimator: Callable[[int, float], None], decks: tuple[str, ...]):
        self.index = index
        self.commander = commander
        self.read = read
        self.position = position
        self.reset_estimator = reset_estimator
        self.params = {v.name: 0.0 for v in p.PARAM_VARIABLES}
        for positioning, name in p.DECK_PARAMS.items():
            self.params[name] = 1.0 if positioning in decks else 0.0
        self.params.update({"stabilizer.estimator": 2.0, "stabilizer.controller": 1.0, "commander.enHighLevel": 1.0, "pm.lowVoltage": 3.2,
                            "posCtlPid.rLimit": FIRMWARE_TILT_LIMIT, "posCtlPid.pLimit": FIRMWARE_TILT_LIMIT})
        self.blocks: dict[int, LogBlock] = {}
        self.group_mask = 0
        self.state_frozen = False  # fault: state-estimate log blocks stop coming
        self.received: list[Received] = []
        self.greeted = False

    # ------------------------------------------------------------------ dispatch

    def handle(self, t: float, datagram: bytes) -> list[bytes]:
        if not datagram:
            return []
        if datagram[0] == 0xFF:  # cflib's UDP scan probe (a null packet)
            return [b"\xff"]
        port, channel = p.split_header(datagram[0])
        data = datagram[1:]
        handler = {
            p.LINK: self._link,
            p.PLATFORM: self._platform,
            p.LOG: self._log,
            p.PARAM: self._param,
            p.MEM: self._mem,
            p.GENERIC_COMMANDER: self._generic_commander,
            p.COMMANDER: self._legacy_commander,
            p.HIGH_LEVEL: self._high_level,
            p.SUPERVISOR: self._supervisor,
            p.LOCALIZATION: self._localization,
        }.get(port)
        if handler is None or not data and port not in (p.LINK,):
            return []
        out = [bytes([p.header(port, ch)]) + payload for ch, payload in handler(t, channel, data) or []]
        if port == p.LINK and channel == p.LINK_SOURCE and not self.greeted:
            self.greeted = True  # a console line, as the firmware prints one at start-up
            out.append(bytes([p.header(p.CONSOLE, 0)]) + f"virtual Crazyflie {self.index}\n".encode()[: p.MAX_DATA])
        return out

    def _note(self, t: float, kind: str, *values: float) -> None:
        self.received.append(Received(t, kind, tuple(float(v) for v in values)))

    # ------------------------------------------------------------------ link, platform, memory

    def _link(self, t, channel, data):
        if channel == p.LINK_ECHO:
            return [(p.LINK_ECHO, data)]
        if channel == p.LINK_SOURCE:
            return [(p.LINK_SOURCE, p.SOURCE_MAGIC)]
        return []

    def _platform(self, t, channel, data):
        if channel == p.PLATFORM_VERSION and data[0] == p.VERSION_PROTOCOL:
            return [(p.PLATFORM_VERSION, bytes([p.VERSION_PROTOCOL, p.PROTOCOL_VERSION]))]
        if channel == p.PLATFORM_COMMAND and data[0] == p.PLATFORM_ARM and len(data) > 1:
            self.commander.arm(self.index, bool(data[1]))
            self._note(t, "arm", data[1])
        return []

    def _mem(self, t, channel, data):
        if channel == p.MEM_INFO and data[0] == p.MEM_INFO_COUNT:
            return [(p.MEM_INFO, bytes([p.MEM_INFO_COUNT, 0]))]
        return []

    # ------------------------------------------------------------------ TOCs, params, logs

    @staticmethod
    def _toc(toc: p.Toc, data: bytes):
        if data[0] == p.TOC_INFO_V2:
            return [(p.TOC_CHANNEL, toc.info_reply())]
        if data[0] == p.TOC_ITEM_V2 and len(data) >= 3:
            item = toc.item_reply(data[1] | data[2] << 8)
            return [(p.TOC_CHANNEL, item)] if item else []
        return []

    def _param(self, t, channel, data):
        if channel == p.TOC_CHANNEL:
            return self._toc(PARAM_TOC, data)
        if len(data) < 2:
            return []
        ident = data[0] | data[1] << 8
        if not 0 <= ident < len(PARAM_TOC.variables):
            return []
        var = PARAM_TOC.variables[ident]
        code = p.TYPES[var.ctype][2]
        if channel == p.PARAM_READ:
            return [(p.PARAM_READ, data[:2] + b"\0" + p.pack_value(code, self.params[var.name]))]
        if channel == p.PARAM_WRITE and not var.read_only:
            value = struct.unpack("<" + code, data[2 : 2 + struct.calcsize("<" + code)])[0]
            self._set_param(t, var.name, float(value))
            return [(p.PARAM_WRITE, data[:2] + p.pack_value(code, self.params[var.name]))]
        return []

    def _set_param(self, t: float, name: str, value: float) -> None:
        self.params[name] = value
        self._note(t, "param", PARAM_TOC.ids[name], value)
        if name == "kalman.resetEstimation" and value:
            self.reset_estimator(self.index, t)
        if name == "commander.enHighLevel":
            self.commander.hl_enabled[self.index] = bool(value)

    def _log(self, t, channel, data):
        if channel == p.TOC_CHANNEL:
            return self._toc(LOG_TOC, data)
        if channel != p.LOG_SETTINGS:
            return []
        command = data[0]
        block_id = data[1] if len(data) > 1 else 0
        status = 0
        if command == p.LOG_RESET:
            self.blocks.clear()
        elif command in (p.LOG_CREATE_V2, p.LOG_APPEND_V2):
            status = self._add_to_block(command, block_id, data[2:])
        elif command == p.LOG_START and block_id in self.blocks:
            block = self.blocks[block_id]
            block.period = max(data[2], 1) * 0.01 if len(data) > 2 else 0.1
            block.running, block.next_due = True, t
        elif command == p.LOG_STOP and block_id in self.blocks:
            self.blocks[block_id].running = False
        elif command == p.LOG_DELETE:
            status = 0 if self.blocks.pop(block_id, None) else 2  # ENOENT
        elif command in (p.LOG_START, p.LOG_STOP):
            status = 2
        else:
            status = 8  # ENOEXEC: command not found
        return [(p.LOG_SETTINGS, bytes([command, block_id, status]))]

    def _add_to_block(self, command: int, block_id: int, spec: bytes) -> int:
        """Parse (type byte, id lo, id hi) triplets; returns an errno (0 when fine)."""
        if command == p.LOG_CREATE_V2:
            if block_id in self.blocks:
                return 17  # EEXIST
            self.blocks[block_id] = LogBlock([])
        elif block_id not in self.blocks:
            return 2  # ENOENT
        block = self.blocks[block_id]
        for k in range(0, len(spec) - 2, 3):
            fetch = spec[k] & 0x0F
            ident = spec[k + 1] | spec[k + 2] << 8
            if ident >= len(LOG_TOC.variables) or fetch not in p.LOG_TYPE_CODE:
                self.blocks.pop(block_id, None)
                return 2
            block.variables.append((ident, p.LOG_TYPE_CODE[fetch]))
        if block.size > p.MAX_LOG_BLOCK_BYTES:
            self.blocks.pop(block_id, None)
            return 7  # E2BIG
        return 0

    def due_logs(self, t: float) -> list[bytes]:
        """The log data packets whose period has come (at most one per block per call)."""
        out = []
        for block_id, block in self.blocks.items():
            if not block.running or t + 1e-9 < block.next_due:
                continue
            block.next_due = max(block.next_due + block.period, t)
            if self.state_frozen and any(ident in _STATE_VARIABLES for ident, _ in block.variables):
                continue
            ms = int(t * 1000) & 0xFFFFFF
            payload = bytes([block_id]) + ms.to_bytes(3, "little")
            payload += b"".join(p.pack_value(code, self.read(LOG_TOC.variables[ident].name)) for ident, code in block.variables)
            out.append(bytes([p.header(p.LOG, p.LOG_DATA)]) + payload)
        return out

    # ------------------------------------------------------------------ flight commands

    def _generic_commander(self, t, channel, data):
        c, i = self.commander, self.index
        if channel == 1 and data[0] == p.META_NOTIFY_SETPOINT_STOP and len(data) >= 5:
            remain_ms = struct.unpack("<I", data[1:5])[0]
            c.notify_setpoint_stop(i, t, remain_ms / 1000.0)
            self._note(t, "notify_stop", remain_ms)
            return []
        if channel != 0:
            return []
        kind = data[0]
        if kind == p.SETPOINT_STOP:
            c.set_low_level(i, t, cmd.STOP)
            self._note(t, "stop")
        elif kind in (p.VELOCITY_WORLD, p.VELOCITY_WORLD_LEGACY) and len(data) >= 17:
            vx, vy, vz, yawrate = struct.unpack("<ffff", data[1:17])
            c.set_low_level(i, t, cmd.VELOCITY, (vx, vy, vz, yawrate if kind == p.VELOCITY_WORLD else -yawrate))
            self._note(t, "velocity", vx, vy, vz, yawrate)
        elif kind in (p.HOVER, p.HOVER_LEGACY) and len(data) >= 17:
            vx, vy, yawrate, z = struct.unpack("<ffff", data[1:17])
            c.set_low_level(i, t, cmd.HOVER, (vx, vy, yawrate, z))
            self._note(t, "hover", vx, vy, yawrate, z)
        elif kind == p.POSITION and len(data) >= 17:
            x, y, z, yaw = struct.unpack("<ffff", data[1:17])
            c.set_low_level(i, t, cmd.POSITION, (x, y, z, yaw))
            self._note(t, "position", x, y, z, yaw)
        else:
            c.set_low_level(i, t, cmd.ATTITUDE)
            self._note(t, "unsupported", kind)  # a setpoint type not modelled here (attitude, z-distance, ...)
        return []

    def _legacy_commander(self, t, channel, data):
        if len(data) < 14:
            return []
        roll, pitch, yawrate, thrust = struct.unpack("<fffH", data[:14])
        # thrust 0 is what cflib sends on close_link: the firmware stops the motors
        self.commander.set_low_level(self.index, t, cmd.STOP if thrust == 0 else cmd.ATTITUDE)
        self._note(t, "rpyt", roll, pitch, yawrate, thrust)
        return []

    def _high_level(self, t, channel, data):
        c, i = self.commander, self.index
        command = data[0]
        group = data[1] if len(data) > 1 else 0
        if command == p.HL_SET_GROUP_MASK:
            self.group_mask = group
            return []
        if group and not group & self.group_mask:
            return []
        if command == p.HL_STOP:
            c.hl_stop(i)
            self._note(t, "hl_stop")
        elif command in (p.HL_TAKEOFF_2, p.HL_LAND_2) and len(data) >= 15:
            _, _, height, yaw, use_current_yaw, duration = struct.unpack("<BBff?f", data[:15])
            plan = c.hl_takeoff if command == p.HL_TAKEOFF_2 else c.hl_land
            plan(i, t, self.position(i), height, duration)  # the virtual drone keeps its yaw either way
            self._note(t, "takeoff" if command == p.HL_TAKEOFF_2 else "land", height, duration, yaw, use_current_yaw)
        elif command == p.HL_GO_TO_2 and len(data) >= 24:
            _, _, relative, _, x, y, z, yaw, duration = struct.unpack("<BBBBfffff", data[:24])
            c.hl_go_to(i, t, self.position(i), np.array([x, y, z]), duration, bool(relative))
            self._note(t, "go_to", x, y, z, duration)
        return []

    def _supervisor(self, t, channel, data):
        c, i = self.commander, self.index
        command = data[0]
        if channel == p.SUPERVISOR_INFO and command == p.SUP_GET_STATE:
            bits = int(self.read("supervisor.info"))
            return [(p.SUPERVISOR_INFO, bytes([command | 0x80]) + bits.to_bytes(2, "little"))]
        if channel != p.SUPERVISOR_COMMAND:
            return []
        if command == p.SUP_EMERGENCY_STOP:
            c.emergency_stop(i)
            self._note(t, "emergency_stop")
        elif command == p.SUP_EMERGENCY_WATCHDOG:
            c.emergency_watchdog(i, t)
        elif command == p.SUP_ARM and len(data) > 1:
            c.arm(i, bool(data[1]))
            self._note(t, "arm", data[1])
            return [(p.SUPERVISOR_COMMAND, bytes([command | 0x80, 1, int(c.armed[i])]))]
        elif command == p.SUP_RECOVER:
            return [(p.SUPERVISOR_COMMAND, bytes([command | 0x80, 1, int(not c.locked[i])]))]
        return []

    def _localization(self, t, channel, data):
        if channel != p.LOC_GENERIC:
            return []
        if data[0] == p.LOC_EMERGENCY_STOP:
            self.commander.emergency_stop(self.index)
            self._note(t, "emergency_stop")
        elif data[0] == p.LOC_EMERGENCY_WATCHDOG:
            self.commander.emergency_watchdog(self.index, t)
        return []
