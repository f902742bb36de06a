"""The Go1 low-level UDP protocol (legged_sdk 3.8): LowCmd / LowState codec and CRC.

Byte layout, checked field by field against the official ``unitree-legged-sdk``
3.8.20231105 wheel (docs/reference.md#go1-low-level-link; its ``robot_interface`` packs and unpacks
these packets). All integers and floats are little-endian, no padding.

LowCmd, 614 bytes (client -> robot)::

    0    head u8[2] = FE EF     2 levelFlag u8 (0xFF low level)   3 frameReserve u8
    4    SN u32[2]              12 version u32[2]                 20 bandWidth u16
    22   20 x MotorCmd (27 bytes each, slot i at 22 + 27 i):
           +0 mode u8  +1 q f32 [rad]  +5 dq f32 [rad/s]  +9 tau i16 (N·m x 256)
           +11 Kp u16 (x 32)  +13 Kd u16 (x 16)  +15 reserved u32[3]
    562  BmsCmd (off u8, reserve u8[3])    566 wirelessRemote u8[40]
    606  reserve u32                       610 crc u32

LowState, 807 bytes (robot -> client)::

    0    the same 22-byte header
    22   IMU: quaternion f32[4] (w, x, y, z), gyroscope f32[3] [rad/s],
         accelerometer f32[3] [m/s²], rpy f32[3] [rad], temperature i8
    75   20 x MotorState (32 bytes each, slot i at 75 + 32 i):
           +0 mode u8  +1 q f32  +5 dq f32  +9 ddq i16 (raw, unscaled)
           +11 tauEst i16 (N·m x 256)  +13 q_raw f32  +17 dq_raw f32
           +21 ddq_raw i16  +23 temperature i8 [°C]  +24 reserved u32[2]
    715  BmsState (24 bytes): version_h, version_l, bms_status, SOC u8 [%],
         current i32, cycle u16, BQ_NTC i8[2], MCU_NTC i8[2], cell_vol u8[10]
    739  footForce i16[4]   747 footForceEst i16[4]   755 tick u32 [ms]
    759  wirelessRemote u8[40]   799 reserve u32   803 crc u32

CRC: CRC-32/MPEG-2 (poly 0x04C11DB7, init 0xFFFFFFFF, no reflection, no final
XOR) over the first ``len // 4 - 1`` little-endian 32-bit words (608 bytes of
LowCmd, 800 of LowState; the bytes between those and the CRC are not
covered), each word fed most significant bit first, stored little-endian in
the last 4 bytes. The wheel drops a state whose header is not FE EF or whose
CRC or length is wrong.

Fixed-point fields are quantised as the wheel's C casts do: the value is
rounded to float32, scaled, and truncated toward zero (``int(1.7 * 32) == 54``
for Kp = 1.7). The wheel silently wraps values out of range (tau = 200 N·m goes
out as -56 N·m); here they raise :class:`ProtocolError` instead.

Motor slots 0..11 are the Go1's joints in the SDK order FR, FL, RR, RL × (hip,
thigh, calf), the same order as :data:`amhe_cli.io.trajectory.GO1_JOINTS`.
Slots 12..19 are unused: a LowCmd fills them as the SDK's ``InitCmdData`` does
(servo mode, q = :data:`POS_STOP_F`, dq = :data:`VEL_STOP_F`, zero gains), so
a command built the official way (``InitCmdData`` then set 12 motors) is
byte-for-byte the same as :meth:`LowCmd.encode`; a LowState leaves them zero.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field

import numpy as np

from amhe_cli.errors import AmheError

LOWCMD_SIZE = 614
LOWSTATE_SIZE = 807
LEVEL_LOW = 0xFF
HEADER = b"\xfe\xef"
MODE_SERVO = 0x0A
MODE_DAMPING = 0x00
N_JOINTS = 12
N_SLOTS = 20
ROBOT_ADDRESS = ("192.168.123.10", 8007)
LOCAL_PORT = 8080
#: legged_sdk's "no position control" value of ``q`` (``UNITREE_LEGGED_SDK::PosStopF``).
POS_STOP_F = 2.146e9
#: legged_sdk's "no velocity control" value of ``dq`` (``UNITREE_LEGGED_SDK::VelStopF``).
VEL_STOP_F = 16000.0
#: Default Kd [N·m·s/rad] of :meth:`LowCmd.damping` (unitree_guide's passive state uses Kd = 8, Kp = 0).
DAMPING_KD = 8.0
#: Wire scale factors: tau and tauEst in 1/256 N·m, Kp in 1/32, Kd in 1/16.
TAU_SCALE, KP_SCALE, KD_SCALE = 256.0, 32.0, 16.0


class ProtocolError(AmheError):
    """A packet that is not a valid LowCmd/LowState (bad length, header or CRC), or a value the wire cannot carry."""


# --- packet layouts (numpy structured dtypes; offsets as in the module docstring) ---

_HEADER_FIELDS = [("head", "u1", 2), ("level", "u1"), ("frame_reserve", "u1"),
                  ("sn", "<u4", 2), ("version", "<u4", 2), ("bandwidth", "<u2")]
_MOTOR_CMD = np.dtype([("mode", "u1"), ("q", "<f4"), ("dq", "<f4"), ("tau", "<i2"),
                       ("kp", "<u2"), ("kd", "<u2"), ("reserve", "<u4", 3)])
_LOWCMD = np.dtype(_HEADER_FIELDS + [
    ("motor", _MOTOR_CMD, N_SLOTS), ("bms_off", "u1"), ("bms_reserve", "u1", 3),
    ("wireless_remote", "u1", 40), ("reserve", "<u4"), ("crc", "<u4")])
_IMU = np.dtype([("quaternion", "<f4", 4), ("gyroscope", "<f4", 3), ("accelerometer", "<f4", 3),
                 ("rpy", "<f4", 3), ("temperature", "i1")])
_MOTOR_STATE = np.dtype([("mode", "u1"), ("q", "<f4"), ("dq", "<f4"), ("ddq", "<i2"), ("tau_est", "<i2"),
                         ("q_raw", "<f4"), ("dq_raw", "<f4"), ("ddq_raw", "<i2"), ("temperature", "i1"),
                         ("reserve", "<u4", 2)])
_BMS_STATE = np.dtype([("version_h", "u1"), ("version_l", "u1"), ("status", "u1"), ("soc", "u1"),
                       ("current", "<i4"), ("cycle", "<u2"), ("bq_ntc", "i1", 2), ("mcu_ntc", "i1", 2),
                       ("cell_vol", "u1", 10)])
_LOWSTATE = np.dtype(_HEADER_FIELDS + [
    ("imu", _IMU), ("motor", _MOTOR_STATE, N_SLOTS), ("bms", _BMS_STATE),
    ("foot_force", "<i2", 4), ("foot_force_est", "<i2", 4), ("tick", "<u4"),
    ("wireless_remote", "u1", 40), ("reserve", "<u4"), ("crc", "<u4")])
assert _MOTOR_CMD.itemsize == 27 and _LOWCMD.itemsize == LOWCMD_SIZE
assert _MOTOR_STATE.itemsize == 32 and _LOWSTATE.itemsize == LOWSTATE_SIZE
assert _LOWSTATE.fields["motor"][1] == 75 and _LOWSTATE.fields["tick"][1] == 755


# --- CRC ---

#: byte -> the same byte with its 8 bits in reverse order.
_BITREV = bytes(int(f"{i:08b}"[::-1], 2) for i in range(256))


def crc32_core(buf: bytes) -> int:
    """The SDK's CRC of a packet: CRC-32/MPEG-2 over its first ``len(buf) // 4 - 1`` 32-bit words.

    Each little-endian word is fed most significant bit first (legged_sdk's
    ``crc32_core`` bit loop; poly 0x04C11DB7, init 0xFFFFFFFF, no reflection,
    no final XOR). Computed with :func:`zlib.crc32`, which is the reflected form
    of the same polynomial: byte-swap each word to big-endian, reverse the bits
    of every byte, run the reflected CRC, undo its final XOR and reflect the
    32-bit result.

    Args:
        buf: a whole packet (bytes-like, at least 4 bytes); the last word (the
            CRC slot) and any trailing bytes after the covered words are ignored.

    Returns:
        The CRC as an unsigned 32-bit int (stored little-endian in the packet's last 4 bytes).

    Raises:
        ProtocolError: ``buf`` shorter than 4 bytes.
    """
    n_words = len(buf) // 4 - 1
    if n_words < 0:
        raise ProtocolError(f"packet of {len(buf)} bytes is too short for a CRC: expected at least 4 bytes")
    words = np.frombuffer(buf, dtype="<u4", count=n_words).astype(">u4").tobytes()
    reflected = zlib.crc32(words.translate(_BITREV)) ^ 0xFFFFFFFF
    return int.from_bytes(reflected.to_bytes(4, "little").translate(_BITREV), "big")


def _check_packet(buf, size: int, what: str) -> np.void:
    """Check length, header and CRC of a packet and view it as its record; raise ProtocolError naming the fault."""
    if not isinstance(buf, (bytes, bytearray, memoryview)):
        raise ProtocolError(f"{what} packet must be bytes, got {type(buf).__name__}")
    buf = bytes(buf)
    if len(buf) != size:
        raise ProtocolError(f"{what} packet is {len(buf)} bytes, expected {size}")
    if buf[:2] != HEADER:
        raise ProtocolError(f"{what} packet header is {buf[:2].hex(' ')}, expected fe ef")
    stored = int.from_bytes(buf[-4:], "little")
    computed = crc32_core(buf)
    if stored != computed:
        raise ProtocolError(f"{what} packet CRC is 0x{stored:08x}, computed 0x{computed:08x} (corrupted packet)")
    dtype = _LOWCMD if size == LOWCMD_SIZE else _LOWSTATE
    return np.frombuffer(buf, dtype=dtype)[0]


def _finish(rec: np.ndarray) -> bytes:
    """Set the header and CRC of a one-element record array and return its bytes."""
    rec["head"] = (0xFE, 0xEF)
    raw = bytearray(rec.tobytes())
    raw[-4:] = crc32_core(raw).to_bytes(4, "little")
    return bytes(raw)


# --- value checks and quantisation ---

_F32_MAX = float(np.finfo(np.float32).max)

def _array(value, shape: tuple[int, ...], dtype, name: str, owner: str) -> np.ndarray:
    """``value`` as a fresh array of ``shape``/``dtype``; AmheError naming the field if the shape is wrong."""
    try:
        arr = np.array(value, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise AmheError(f"{owner}.{name} must be numbers of shape {shape}: {exc}") from None
    if arr.shape != shape:
        raise AmheError(f"{owner}.{name} has shape {arr.shape}, expected {shape}")
    return arr


def _int_array(value, shape: tuple[int, ...], name: str, owner: str) -> np.ndarray:
    """Whole numbers as an int64 array; AmheError if any value is not a whole number."""
    arr = _array(value, shape, np.float64, name, owner)
    if not (arr == np.round(arr)).all():  # False for NaN/inf too
        raise AmheError(f"{owner}.{name} must hold whole numbers, got {arr.tolist()}")
    return arr.astype(np.int64)


def _float32(values: np.ndarray, name: str) -> np.ndarray:
    """``values`` rounded to float32 as the wire carries them; ProtocolError if any is NaN/inf or overflows float32."""
    arr = np.asarray(values, dtype=np.float64)
    ok = np.abs(arr) <= _F32_MAX  # False for NaN
    if not ok.all():
        i = np.flatnonzero(~ok.ravel())[0]
        raise ProtocolError(f"{name}[{i}] = {float(arr.ravel()[i])!r} cannot be sent: expected a finite float32")
    return arr.astype(np.float32)


def _fixed(values: np.ndarray, scale: float, lo: int, hi: int, name: str, unit: str = "") -> np.ndarray:
    """Fixed-point wire value ``trunc(float32(v) * scale)`` (the wheel's C cast); ProtocolError outside [lo, hi]."""
    scaled = np.trunc(_float32(values, name).astype(np.float64) * scale)
    bad = (scaled < lo) | (scaled > hi)
    if bad.any():
        i = np.flatnonzero(bad.ravel())[0]
        raise ProtocolError(f"{name}[{i}] = {np.ravel(values)[i]:g}{unit} is out of the wire's range "
                            f"[{lo / scale:g}, {(hi + 1) / scale:g}){unit}")
    return scaled.astype(np.int64)


def _ints(values: np.ndarray, lo: int, hi: int, name: str) -> np.ndarray:
    """Integers checked to lie in [lo, hi]; ProtocolError naming the first bad one."""
    arr = np.asarray(values, dtype=np.int64)
    bad = (arr < lo) | (arr > hi)
    if bad.any():
        i = np.flatnonzero(bad.ravel())[0]
        where = name if arr.ndim == 0 else f"{name}[{i}]"
        raise ProtocolError(f"{where} = {np.ravel(arr)[i]} is out of the wire's range [{lo}, {hi}]")
    return arr


def _trusted(cls, **fields):
    """An instance of dataclass ``cls`` from already-typed fields, skipping ``__post_init__`` (decode's fast path)."""
    obj = object.__new__(cls)
    obj.__dict__.update(fields)
    return obj


# --- LowCmd ---

def _lowcmd_template() -> np.ndarray:
    """The SDK's ``InitCmdData`` packet (before CRC): header, level 0xFF, every slot servo with stop values."""
    rec = np.zeros(1, dtype=_LOWCMD)
    rec["head"] = (0xFE, 0xEF)
    rec["level"] = LEVEL_LOW
    rec["motor"]["mode"] = MODE_SERVO
    rec["motor"]["q"] = POS_STOP_F
    rec["motor"]["dq"] = VEL_STOP_F
    return rec


_LOWCMD_TEMPLATE = _lowcmd_template()


@dataclass(eq=False)
class LowCmd:
    """A low-level command to the 12 joints (legged_sdk 3.8 ``LowCmd``, 614 bytes; module docstring).

    Each joint's motor applies ``tau + Kp (q - q_now) + Kd (dq - dq_now)``.
    Arrays are (12,) in the SDK motor order (FR, FL, RR, RL × hip, thigh, calf)
    and are copied to fresh arrays on construction.

    Attributes:
        mode: (12,) uint8 motor mode, :data:`MODE_SERVO` (0x0A) or :data:`MODE_DAMPING` (0x00).
        q: (12,) float64 position target [rad] (:data:`POS_STOP_F` disables the position term).
        dq: (12,) float64 velocity target [rad/s] (:data:`VEL_STOP_F` disables the velocity term).
        tau: (12,) float64 feed-forward torque [N·m], wire range [-128, 128), step 1/256.
        kp: (12,) float64 position gain [N·m/rad], wire range [0, 2048), step 1/32.
        kd: (12,) float64 velocity gain [N·m·s/rad], wire range [0, 4096), step 1/16.
        level: levelFlag byte, :data:`LEVEL_LOW` (0xFF).

    Raises:
        AmheError: an array of the wrong shape or a non-integer mode.
    """

    mode: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    tau: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    level: int = LEVEL_LOW

    def __post_init__(self):
        mode = _int_array(self.mode, (N_JOINTS,), "mode", "LowCmd")
        if ((mode < 0) | (mode > 255)).any():
            raise AmheError(f"LowCmd.mode must be bytes 0..255, got {mode.tolist()}")
        self.mode = mode.astype(np.uint8)
        for name in ("q", "dq", "tau", "kp", "kd"):
            setattr(self, name, _array(getattr(self, name), (N_JOINTS,), np.float64, name, "LowCmd"))
        self.level = int(self.level)

    def encode(self) -> bytes:
        """The 614-byte packet, header and CRC set, values quantised as the wheel does (module docstring).

        Slots 12..19 carry the SDK's ``InitCmdData`` filler.

        Raises:
            ProtocolError: a mode other than 0x0A/0x00, a level outside 0..255, NaN or
                float32-overflowing q/dq, negative or out-of-range Kp/Kd, tau outside [-128, 128) N·m.
        """
        bad_mode = (self.mode != MODE_SERVO) & (self.mode != MODE_DAMPING)
        if bad_mode.any():
            i = np.flatnonzero(bad_mode)[0]
            raise ProtocolError(f"LowCmd.mode[{i}] = 0x{self.mode[i]:02x}: expected 0x0a (servo) or 0x00 (damping)")
        if not 0 <= self.level <= 255:
            raise ProtocolError(f"LowCmd.level = {self.level} is not a byte: expected {LEVEL_LOW:#x}")
        for name in ("kp", "kd"):
            gains = getattr(self, name)
            if (gains < 0).any():
                i = np.flatnonzero(gains < 0)[0]
                raise ProtocolError(f"LowCmd.{name}[{i}] = {gains[i]:g} is negative: expected a gain >= 0")
        rec = _LOWCMD_TEMPLATE.copy()
        rec["level"] = self.level
        m = rec["motor"][0, :N_JOINTS]  # a view: writes go into rec
        m["mode"] = self.mode
        m["q"] = _float32(self.q, "LowCmd.q")
        m["dq"] = _float32(self.dq, "LowCmd.dq")
        m["tau"] = _fixed(self.tau, TAU_SCALE, -2**15, 2**15 - 1, "LowCmd.tau", " N·m")
        m["kp"] = _fixed(self.kp, KP_SCALE, 0, 2**16 - 1, "LowCmd.kp")
        m["kd"] = _fixed(self.kd, KD_SCALE, 0, 2**16 - 1, "LowCmd.kd")
        return _finish(rec)

    @classmethod
    def decode(cls, buf: bytes) -> "LowCmd":
        """Parse a 614-byte LowCmd packet (slots 0..11; the rest is ignored).

        Raises:
            ProtocolError: wrong length, header not FE EF, or CRC mismatch (the message says which).
        """
        rec = _check_packet(buf, LOWCMD_SIZE, "LowCmd")
        m = rec["motor"][:N_JOINTS]
        return _trusted(cls, mode=m["mode"].copy(), q=m["q"].astype(np.float64), dq=m["dq"].astype(np.float64),
                        tau=m["tau"] / TAU_SCALE, kp=m["kp"] / KP_SCALE, kd=m["kd"] / KD_SCALE,
                        level=int(rec["level"]))

    @classmethod
    def damping(cls, kd: float = DAMPING_KD) -> "LowCmd":
        """All 12 motors in damping mode (0x00) with q, dq, tau, Kp = 0 and Kd = ``kd`` [N·m·s/rad]."""
        zeros = np.zeros(N_JOINTS)
        return cls(mode=np.full(N_JOINTS, MODE_DAMPING, dtype=np.uint8), q=zeros, dq=zeros, tau=zeros,
                   kp=zeros, kd=np.full(N_JOINTS, float(kd)))


# --- LowState ---

@dataclass(eq=False)
class LowState:
    """The robot's low-level state (legged_sdk 3.8 ``LowState``, 807 bytes; module docstring).

    Arrays are copied to fresh arrays on construction; joint arrays are (12,) in
    the SDK motor order (FR, FL, RR, RL × hip, thigh, calf).

    Attributes:
        quaternion: (4,) IMU orientation (w, x, y, z), body to world.
        gyroscope: (3,) body angular velocity [rad/s], body frame.
        accelerometer: (3,) specific force [m/s²], body frame.
        rpy: (3,) roll, pitch, yaw [rad].
        imu_temperature: IMU temperature [°C], -128..127.
        motor_mode: (12,) uint8 motor modes.
        q, dq: (12,) joint positions [rad] and velocities [rad/s].
        ddq: (12,) joint accelerations in the wire's raw int16 units (unscaled).
        tau_est: (12,) estimated joint torques [N·m], step 1/256, range [-128, 128).
        motor_temperature: (12,) int64 motor temperatures [°C], -128..127.
        foot_force, foot_force_est: (4,) foot contact sensor readings (raw int16 counts), FR, FL, RR, RL.
        tick: robot clock [ms], uint32 (wraps after 49.7 days).
        level: levelFlag byte (0xFF in low-level mode).
        wireless_remote: the 40 raw bytes of the handheld remote's state.
        battery_soc: battery state of charge [%], 0..255.

    Raises:
        AmheError: an array of the wrong shape, or a non-integer where the wire holds integers.
    """

    quaternion: np.ndarray
    gyroscope: np.ndarray
    accelerometer: np.ndarray
    rpy: np.ndarray
    imu_temperature: int
    motor_mode: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    tau_est: np.ndarray
    motor_temperature: np.ndarray
    foot_force: np.ndarray
    foot_force_est: np.ndarray
    tick: int
    level: int = LEVEL_LOW
    wireless_remote: bytes = field(default=bytes(40))
    battery_soc: int = 0

    def __post_init__(self):
        for name, n in (("quaternion", 4), ("gyroscope", 3), ("accelerometer", 3), ("rpy", 3),
                        ("q", N_JOINTS), ("dq", N_JOINTS), ("ddq", N_JOINTS), ("tau_est", N_JOINTS),
                        ("foot_force", 4), ("foot_force_est", 4)):
            setattr(self, name, _array(getattr(self, name), (n,), np.float64, name, "LowState"))
        self.motor_mode = _int_array(self.motor_mode, (N_JOINTS,), "motor_mode", "LowState")
        self.motor_temperature = _int_array(self.motor_temperature, (N_JOINTS,), "motor_temperature", "LowState")
        for name in ("imu_temperature", "tick", "level", "battery_soc"):
            setattr(self, name, int(_int_array(getattr(self, name), (), name, "LowState")))
        if ((self.motor_mode < 0) | (self.motor_mode > 255)).any():
            raise AmheError(f"LowState.motor_mode must be bytes 0..255, got {self.motor_mode.tolist()}")
        self.motor_mode = self.motor_mode.astype(np.uint8)
        self.wireless_remote = bytes(self.wireless_remote)
        if len(self.wireless_remote) != 40:
            raise AmheError(f"LowState.wireless_remote is {len(self.wireless_remote)} bytes, expected 40")

    def encode(self) -> bytes:
        """The 807-byte packet as the robot sends it, header and CRC set (slots 12..19 and BMS fields but SOC zero).

        Raises:
            ProtocolError: a value the wire cannot carry (NaN, float32 overflow, an
                integer field out of its range, tau_est outside [-128, 128) N·m).
        """
        rec = np.zeros(1, dtype=_LOWSTATE)
        rec["level"] = _ints(self.level, 0, 255, "LowState.level")
        imu = rec["imu"]  # a view
        for name in ("quaternion", "gyroscope", "accelerometer", "rpy"):
            imu[name] = _float32(getattr(self, name), f"LowState.{name}")
        imu["temperature"] = _ints(self.imu_temperature, -128, 127, "LowState.imu_temperature")
        m = rec["motor"][0, :N_JOINTS]  # a view: writes go into rec
        m["mode"] = self.motor_mode
        m["q"] = _float32(self.q, "LowState.q")
        m["dq"] = _float32(self.dq, "LowState.dq")
        m["ddq"] = _fixed(self.ddq, 1.0, -2**15, 2**15 - 1, "LowState.ddq")
        m["tau_est"] = _fixed(self.tau_est, TAU_SCALE, -2**15, 2**15 - 1, "LowState.tau_est", " N·m")
        m["temperature"] = _ints(self.motor_temperature, -128, 127, "LowState.motor_temperature")
        rec["bms"]["soc"] = _ints(self.battery_soc, 0, 255, "LowState.battery_soc")
        rec["foot_force"] = _fixed(self.foot_force, 1.0, -2**15, 2**15 - 1, "LowState.foot_force")
        rec["foot_force_est"] = _fixed(self.foot_force_est, 1.0, -2**15, 2**15 - 1, "LowState.foot_force_est")
        rec["tick"] = _ints(self.tick, 0, 2**32 - 1, "LowState.tick")
        rec["wireless_remote"] = np.frombuffer(self.wireless_remote, dtype=np.uint8)
        return _finish(rec)

    @classmethod
    def decode(cls, buf: bytes) -> "LowState":
        """Parse an 807-byte LowState packet (slots 0..11; floats widened to float64, fixed-point scaled).

        Raises:
            ProtocolError: wrong length, header not FE EF, or CRC mismatch (the message says which).
        """
        rec = _check_packet(buf, LOWSTATE_SIZE, "LowState")
        imu = rec["imu"]
        m = rec["motor"][:N_JOINTS]
        f64 = np.float64
        return _trusted(cls, quaternion=imu["quaternion"].astype(f64), gyroscope=imu["gyroscope"].astype(f64),
                        accelerometer=imu["accelerometer"].astype(f64), rpy=imu["rpy"].astype(f64),
                        imu_temperature=int(imu["temperature"]), motor_mode=m["mode"].copy(),
                        q=m["q"].astype(f64), dq=m["dq"].astype(f64), ddq=m["ddq"].astype(f64),
                        tau_est=m["tau_est"] / TAU_SCALE, motor_temperature=m["temperature"].astype(np.int64),
                        foot_force=rec["foot_force"].astype(f64), foot_force_est=rec["foot_force_est"].astype(f64),
                        tick=int(rec["tick"]), level=int(rec["level"]),
                        wireless_remote=rec["wireless_remote"].tobytes(), battery_soc=int(rec["bms"]["soc"]))

    @classmethod
    def zeros(cls) -> "LowState":
        """A state of all zeros except the identity quaternion (1, 0, 0, 0); level 0xFF."""
        z12, z4, z3 = np.zeros(N_JOINTS), np.zeros(4), np.zeros(3)
        return cls(quaternion=np.array([1.0, 0.0, 0.0, 0.0]), gyroscope=z3, accelerometer=z3, rpy=z3,
                   imu_temperature=0, motor_mode=np.zeros(N_JOINTS, dtype=np.uint8), q=z12, dq=z12, ddq=z12,
                   tau_est=z12, motor_temperature=np.zeros(N_JOINTS, dtype=np.int64), foot_force=z4,
                   foot_force_est=z4, tick=0)
