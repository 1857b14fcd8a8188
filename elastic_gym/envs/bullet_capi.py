"""PyBullet's C client API called from compiled code: physics substeps without Python.

PyBullet's Python functions build commands of its C client API, which its extension
module exports; the numba functions below issue the same commands with the same
arguments (see each one's docstring), so a world stepped through them advances bit for
bit as through the Python functions (tested), with no return to Python between the
substeps of a control period. Numba calls them by symbol name, as
`elastic_gym.model.lapack` calls LAPACK.

A Python connection's C handle sits in the extension's static table
``sPhysicsClients1[physicsClientId]``, which is not exported; the module's ELF symbol
table (kept in PyPI's Linux wheels) gives its address. `client_slot` returns a live
view of a client's entry (0 once disconnected), read by the kernels at every call, or
None where the table cannot be found (another platform, a stripped build): the simulator
then steps through the Python functions.
"""

from __future__ import annotations

import ctypes
import functools
import struct
import sys

import llvmlite.binding as llvm
import numpy as np
from numba import njit, types

from elastic_gym.envs.pybullet_quiet import pybullet as p

_HANDLE = types.intp  # C pointers as integers (the same registers on x86-64 and arm64)
_TABLE = "sPhysicsClients1"  # pybullet.c: static b3PhysicsClientHandle [MAX_PHYSICS_CLIENTS]
_MAX_CLIENTS = 1024  # MAX_PHYSICS_CLIENTS of pybullet.c
_ANCHOR = "b3SubmitClientCommandAndWaitStatus"  # an exported function: the load address

TORQUE_CONTROL = 1  # CONTROL_MODE_TORQUE of SharedMemoryPublic.h
ACTUAL_STATE_UPDATE_COMPLETED = 21  # EnumSharedMemoryServerStatus
SENSOR_STATE_DOUBLES = 9  # b3JointSensorState: q, q', reaction wrench (6), motor torque

# the kernels' return codes
OK, DISCONNECTED, STATE_FAILED = 0, 1, 2
ERRORS = {
    DISCONNECTED: "Not connected to physics server.",  # PyBullet's own messages
    STATE_FAILED: "getJointState failed.",
}


def _load() -> ctypes.CDLL | None:
    """The loaded extension module, opened again for its symbols (None if it cannot be)."""
    try:
        return ctypes.CDLL(p.__file__)
    except OSError:
        return None


_LIBRARY = _load()
_MISSING: list[str] = []  # C API functions this build does not export


def _address(name: str) -> int | None:
    """Where the exported C function ``name`` is, or None."""
    function = getattr(_LIBRARY, name, None)
    return None if function is None else ctypes.cast(function, ctypes.c_void_p).value


def _external(name: str, signature) -> types.ExternalFunction:
    """The exported C function ``name``, callable from numba under a symbol of its own
    (by name, so that numba's cache holds no address). A function the build does not
    export stays unbound: no handle is then read (`client_slot`), so no kernel
    calling it is compiled."""
    symbol, address = f"elastic_gym_{name}", _address(name)
    if address is None:
        _MISSING.append(name)
    else:
        llvm.add_symbol(symbol, address)
    return types.ExternalFunction(symbol, signature)


_submit = _external(_ANCHOR, _HANDLE(_HANDLE, _HANDLE))
_status_type = _external("b3GetStatusType", types.intc(_HANDLE))
_step_command = _external("b3InitStepSimulationCommand", _HANDLE(_HANDLE))
_control_command = _external("b3JointControlCommandInit2", _HANDLE(_HANDLE, types.intc, types.intc))
_set_torque = _external(
    "b3JointControlSetDesiredForceTorque", types.intc(_HANDLE, types.intc, types.double)
)
_state_command = _external("b3RequestActualStateCommandInit", _HANDLE(_HANDLE, types.intc))
_joint_state = _external("b3GetJointState", types.intc(_HANDLE, _HANDLE, types.intc, _HANDLE))
if _address("b3CanSubmitCommand") is None:  # client_slot's check of a handle
    _MISSING.append("b3CanSubmitCommand")


def _elf_symbols(path: str, names: tuple[str, ...]) -> dict[str, tuple[int, int]]:
    """(value (the address before loading), size) of each named symbol found once in the
    symbol table (``SHT_SYMTAB``) of the 64-bit little-endian ELF file at ``path``; empty
    when the file is not one or has no such table."""
    with open(path, "rb") as f:
        header = f.read(64)
        if header[:6] != b"\x7fELF\x02\x01":
            return {}
        (sections_at,) = struct.unpack_from("<Q", header, 0x28)
        entry_size, count = struct.unpack_from("<HH", header, 0x3A)
        f.seek(sections_at)
        sections = [
            struct.unpack_from("<IIQQQQII", f.read(entry_size)) for _ in range(count)
        ]  # name, type, flags, address, offset, size, link, info
        tables = [s for s in sections if s[1] == 2]  # SHT_SYMTAB
        if not tables:
            return {}
        _, _, _, _, offset, size, link, _ = tables[0]
        f.seek(offset)
        symbols = np.frombuffer(
            f.read(size),
            dtype=[("name", "<u4"), ("info", "u1"), ("other", "u1"), ("section", "<u2"),
                   ("value", "<u8"), ("size", "<u8")],
        )  # fmt: skip
        f.seek(sections[link][4])
        strings = f.read(sections[link][5])
    values = {}
    for name in names:
        at = strings.find(b"\0" + name.encode() + b"\0")
        hits = symbols[symbols["name"] == at + 1]
        if at >= 0 and len(hits) == 1:
            values[name] = (int(hits["value"][0]), int(hits["size"][0]))
    return values


@functools.cache
def _table_address() -> int | None:
    """Where ``sPhysicsClients1`` is in this process, or None if it cannot be found."""
    if not sys.platform.startswith("linux") or _MISSING:
        return None
    try:
        values = _elf_symbols(p.__file__, (_TABLE, _ANCHOR))
    except OSError:
        return None
    if len(values) != 2 or values[_TABLE][1] != 8 * _MAX_CLIENTS:  # not the known table
        return None
    loaded = _address(_ANCHOR)
    return None if loaded is None else loaded - values[_ANCHOR][0] + values[_TABLE][0]


def _can_submit(handle: int) -> int:
    """``b3CanSubmitCommand(handle)``."""
    function = _LIBRARY.b3CanSubmitCommand  # type: ignore[union-attr]  # table found: loaded
    function.restype, function.argtypes = ctypes.c_int, [ctypes.c_void_p]
    return function(handle)


def client_slot(client: int) -> np.ndarray | None:
    """A live int64 view (1,) of PyBullet's handle of the connection ``client`` (0 once
    it is disconnected), or None when the handle cannot be read here."""
    table = _table_address()
    if table is None or not 0 <= client < _MAX_CLIENTS:
        return None
    slot = np.ctypeslib.as_array((ctypes.c_int64 * 1).from_address(table + 8 * client))
    if slot[0] == 0 or _can_submit(int(slot[0])) != 1:
        return None
    return slot


def world_arrays(client: int, bodies: list[int], joints: list[int]) -> tuple:
    """The ``world`` of `substep`: (bodies, the joints' velocity indices per body
    (N, n), the joint indices, a sensor buffer), for the bodies ``bodies`` of the
    connection ``client`` and their actuated joints ``joints``."""
    velocity_index = [
        [p.getJointInfo(body, j, physicsClientId=client)[4] for j in joints] for body in bodies
    ]
    return (
        np.array(bodies, dtype=np.intc),
        np.array(velocity_index, dtype=np.intc),
        np.array(joints, dtype=np.intc),
        np.empty(SENSOR_STATE_DOUBLES),
    )


@njit(cache=True)
def apply_torques(handle, bodies, dofs, torques, extra):
    """``setJointMotorControlArray(body, joints, TORQUE_CONTROL, forces=torques[k] (+
    extra[k]))`` for every arm k (``extra`` (N, n), or (N, 0): none):
    ``b3JointControlCommandInit2`` and one ``b3JointControlSetDesiredForceTorque`` per
    joint at its velocity index ``dofs[k, j]``."""
    added = extra.shape[1] > 0
    for k in range(bodies.shape[0]):
        command = _control_command(handle, bodies[k], TORQUE_CONTROL)
        for j in range(dofs.shape[1]):
            torque = torques[k, j] + extra[k, j] if added else torques[k, j]
            _set_torque(command, dofs[k, j], torque)
        _submit(handle, command)


@njit(cache=True)
def step_world(handle):
    """``stepSimulation``: ``b3InitStepSimulationCommand``."""
    _submit(handle, _step_command(handle))


@njit(cache=True)
def read_joint_states(handle, bodies, joints, states, sensor):
    """``getJointStates`` of every arm (``b3RequestActualStateCommandInit``, then
    ``b3GetJointState`` per joint): q, q' per joint, arm by arm, into the flat ``states``;
    ``sensor``: a buffer of `SENSOR_STATE_DOUBLES`. Returns a code."""
    n = joints.shape[0]
    for k in range(bodies.shape[0]):
        status = _submit(handle, _state_command(handle, bodies[k]))
        if _status_type(status) != ACTUAL_STATE_UPDATE_COMPLETED:
            return STATE_FAILED
        for j in range(n):
            if _joint_state(handle, status, joints[j], sensor.ctypes.data) == 0:
                return STATE_FAILED
            states[2 * (k * n + j)] = sensor[0]
            states[2 * (k * n + j) + 1] = sensor[1]
    return OK


@njit(cache=True)
def substep(handle, world, torques, extra, states):
    """One physics step of a world under the joint torques ``torques`` (+ ``extra``, or
    (N, 0): none), its joint states read into ``states``: `apply_torques`,
    `step_world`, `read_joint_states`. ``world``: (bodies, velocity indices
    (N, n), joint indices, sensor buffer). Returns a code."""
    bodies, dofs, joints, sensor = world
    apply_torques(handle, bodies, dofs, torques, extra)
    step_world(handle)
    return read_joint_states(handle, bodies, joints, states, sensor)


def raise_for(code: int) -> None:
    """PyBullet's error for a kernel's return code (none for `OK`)."""
    if code != OK:
        raise p.error(ERRORS[code])
