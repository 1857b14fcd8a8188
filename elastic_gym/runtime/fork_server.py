"""Start worker processes as forks of a server that has already imported what they need.

A spawned process is a fresh interpreter that imports everything again (seconds for
numba, SciPy, PyBullet, Pinocchio); `start_process` forks it instead from a server
(``multiprocessing``'s forkserver) that imported the ``preload`` modules once, then
readied numba's compiler (`numba_ready`). The child sees what a spawned one would: a
server serves one environment and ``sys.path`` (it is started with them; another
combination gets its own server, an idle one is stopped) and any preload list it
imported, and each child takes this process's standard output and error, working folder,
``sys.argv`` and ``__main__`` handling at its own start, and a fresh NumPy global seed.
A server ends when this process ends, however: it exits when its "alive" pipe, held by
this process alone, closes (children close their copy at once), and a child can ask the
kernel to kill it when the server ends (``target`` receives the pid of its parent).
Elsewhere (not Linux, Python < 3.11, ``python -E``, another forkserver launch) they spawn.
"""

from __future__ import annotations

import ast
import contextlib
import functools
import hashlib
import importlib
import inspect
import io
import multiprocessing
import os
import signal
import sys
import textwrap
import threading
import time
from collections.abc import Callable, Sequence
from multiprocessing import context, forkserver, popen_forkserver, process, reduction, spawn, util
from typing import Any

PACKAGE = __name__.split(".")[0]
SERVER_EXIT = 2.0  # s a stopped server gets to exit on its own before it is killed
_LAUNCH_VARIABLES = ("PYTHONPATH", "PYTHONSAFEPATH")  # set for the server's start only
READY = f"{PACKAGE}.runtime.numba_ready"  # imported last by every server


# what this module uses of multiprocessing's forkserver beyond its public functions
_INTERNALS = ("_forkserver_pid", "_forkserver_alive_fd", "_forkserver_address", "ensure_running")
# the syntax tree of CPython 3.11's popen_forkserver.Popen._launch, which _Popen._launch
# follows: a Python with another one spawns
_LAUNCH_FOLLOWED = "142bcf42d88ca53c"


def _launch_followed() -> bool:
    """Whether this Python's ``popen_forkserver.Popen._launch`` is the one `_Popen` follows
    (its syntax tree, comments and layout aside)."""
    try:
        launch = getattr(popen_forkserver.Popen, "_launch", None)
        source = textwrap.dedent(inspect.getsource(launch))  # type: ignore[arg-type]
    except (OSError, TypeError):  # no such method, or no source shipped
        return False
    tree = ast.dump(ast.parse(source)).encode()
    return hashlib.sha256(tree).hexdigest()[: len(_LAUNCH_FOLLOWED)] == _LAUNCH_FOLLOWED


@functools.cache
def available() -> bool:
    """Whether processes can be forked from a server here (else they are spawned)."""
    return (
        sys.platform.startswith("linux")  # macOS: Accelerate and the ObjC runtime are not fork-safe
        and "forkserver" in multiprocessing.get_all_start_methods()
        and sys.version_info >= (3, 11)  # PYTHONSAFEPATH: the server resolves imports as we do
        and not sys.flags.ignore_environment
        and all(hasattr(forkserver.ForkServer(), name) for name in _INTERNALS)
        and hasattr(forkserver, "_forkserver")
        and _launch_followed()
    )


def owned(module: str) -> bool:
    """Whether ``module`` belongs to this package (safe to import in a long-lived server:
    no user code, which could change on disk or act at import)."""
    return module == PACKAGE or module.startswith(PACKAGE + ".")


class _InheritedFd:
    """A file descriptor of this process that the child receives as its own (pickled while
    a process starts, like a ``Connection``); ``None`` if this process has no such fd."""

    def __init__(self, fd: int) -> None:
        self.fd = fd

    def __reduce__(self) -> tuple:
        try:
            os.fstat(self.fd)
        except OSError:
            return (type(None), ())
        return (_InheritedFd._detach, (reduction.DupFd(self.fd),))

    @staticmethod
    def _detach(dup: Any) -> int:
        return dup.detach()


def _launch_path() -> list[str]:
    """``sys.path`` as a child receives it (multiprocessing's preparation data)."""
    return [str(entry) for entry in spawn.get_preparation_data("server")["sys_path"]]


@contextlib.contextmanager
def _launch_environment(path: list[str]) -> Any:
    """While the server starts: it finds modules where this process does (its ``sys.path``
    starts as ours, without the working folder a ``-c`` command would put first)."""
    saved = {key: os.environ.get(key) for key in _LAUNCH_VARIABLES}
    os.environ["PYTHONPATH"] = os.pathsep.join(path)
    os.environ["PYTHONSAFEPATH"] = "1"
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


class _Server:
    """One forkserver: its preload list and environment, and the processes it forked."""

    def __init__(self, preload: list[str], path: list[str]) -> None:
        self.forkserver: Any = forkserver.ForkServer()
        self.forkserver.set_forkserver_preload(preload)
        self.path = path
        self.children: list[process.BaseProcess] = []

    def busy(self) -> bool:
        self.children = [child for child in self.children if child.is_alive()]
        return bool(self.children)

    def stop(self) -> None:
        """Close its alive pipe (it exits), killed if it has not after `SERVER_EXIT` s."""
        server = self.forkserver
        pid = server._forkserver_pid
        if pid is None:
            return
        os.close(server._forkserver_alive_fd)
        server._forkserver_alive_fd = server._forkserver_pid = None
        deadline = time.monotonic() + SERVER_EXIT
        while os.waitpid(pid, os.WNOHANG)[0] == 0:
            if time.monotonic() > deadline:
                os.kill(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
                break
            time.sleep(0.01)

    def forget(self) -> None:
        """In a forked copy of this process: let the server go (it is not ours)."""
        alive = self.forkserver._forkserver_alive_fd
        if alive is not None:
            with contextlib.suppress(OSError):
                os.close(alive)


class _Popen(popen_forkserver.Popen):
    """``multiprocessing``'s forkserver ``Popen``, with a server of ours rather than the
    module's global one."""

    def __init__(self, process_obj: Any, server: forkserver.ForkServer) -> None:
        self._server = server
        super().__init__(process_obj)

    def _launch(self, process_obj: Any) -> None:  # popen_forkserver.Popen._launch
        prep_data = spawn.get_preparation_data(process_obj._name)
        buf = io.BytesIO()
        context.set_spawning_popen(self)
        try:
            reduction.dump(prep_data, buf)
            reduction.dump(process_obj, buf)
        finally:
            context.set_spawning_popen(None)
        self.sentinel, w = self._server.connect_to_new_process(self._fds)  # type: ignore[attr-defined]
        parent_w = os.dup(w)  # the child's sentinel of this process
        close = util.close_fds  # type: ignore[attr-defined]  # (not in typeshed)
        self.finalizer = util.Finalize(self, close, (parent_w, self.sentinel))
        with open(w, "wb", closefd=True) as f:
            f.write(buf.getbuffer())
        self.pid = forkserver.read_signed(self.sentinel)


class _Process(context.ForkServerProcess):
    """A process forked by a given server (which is not pickled with it)."""

    def __init__(self, server: forkserver.ForkServer, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self._server = server

    def __getstate__(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k != "_server"}

    def _Popen(self, process_obj: Any) -> _Popen:  # type: ignore[override]
        return _Popen(process_obj, self._server)


_servers: dict[tuple, _Server] = {}
_lock = threading.Lock()


def _forget_servers() -> None:
    for server in _servers.values():
        server.forget()
    _servers.clear()


os.register_at_fork(after_in_child=_forget_servers)


def _server(preload: Sequence[str]) -> _Server:
    """A server for this environment and ``sys.path`` that has imported at least
    ``preload`` (a server that imported more serves fewer), else a new one (idle servers
    of other combinations are stopped)."""
    path = _launch_path()
    setting = (tuple(sorted(os.environ.items())), tuple(path), spawn.get_executable())
    with _lock:
        for (other_setting, loaded), server in _servers.items():
            if other_setting == setting and set(preload) <= set(loaded):
                return server
        for other in [k for k, s in _servers.items() if not s.busy()]:
            _servers.pop(other).stop()
        server = _servers[setting, tuple(preload)] = _Server(list(preload), path)
        return server


def _child(
    target: Callable[..., Any],
    parent: int,
    args: tuple,
    environment: dict[str, str | None],
    stdout: int | None,
    stderr: int | None,
) -> None:
    """First code of a forked child: what a spawned process would have, then ``target``."""
    inherited: Any = forkserver._forkserver
    if inherited._forkserver_alive_fd is not None:  # the server's: it must see us gone
        os.close(inherited._forkserver_alive_fd)
        inherited._forkserver_alive_fd = inherited._forkserver_address = None
    for fd, given in ((1, stdout), (2, stderr)):
        stream = sys.stdout if fd == 1 else sys.stderr
        if stream is not None:
            with contextlib.suppress(Exception):
                stream.flush()
        if given is None:
            with contextlib.suppress(OSError):
                os.close(fd)
        else:
            os.dup2(given, fd)
            os.close(given)
    stdout_stream: Any = sys.stdout
    if stdout_stream is not None and not getattr(stdout_stream, "write_through", True):
        with contextlib.suppress(Exception):  # as a new interpreter would buffer it
            stdout_stream.reconfigure(line_buffering=os.isatty(1))
    for key, value in environment.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value
    importlib.invalidate_caches()  # files created since the server listed the folders
    if (random := sys.modules.get("numpy.random")) is not None:
        random.seed()  # a spawned process seeds NumPy's global generator afresh
    target(parent, *args)


def start_process(
    target: Callable[..., Any], args: tuple, preload: Sequence[str] = ()
) -> process.BaseProcess:
    """Start a daemon process that runs ``target(parent, *args)``, ``parent`` the pid of
    its parent process (a fork server, or this process where it spawns).

    ``preload``: the modules its code needs, imported by the server besides the module
    of ``target`` (this package's or installed libraries, never user code: see `owned`).
    Started in this process's current environment (see the module docstring).
    """
    names = list(dict.fromkeys([__name__, target.__module__, *preload, READY]))
    if not available() or not owned(target.__module__):
        spawned = multiprocessing.get_context("spawn").Process(
            target=target, args=(os.getpid(), *args), daemon=True
        )
        spawned.start()
        return spawned
    server = _server(names)
    environment = {key: os.environ.get(key) for key in _LAUNCH_VARIABLES}  # ours, for the child
    with _lock, _launch_environment(server.path):  # in case the server has to start (again)
        server.forkserver.ensure_running()
        parent = server.forkserver._forkserver_pid
        child = _Process(
            server.forkserver,
            target=_child,
            args=(target, parent, args, environment, _InheritedFd(1), _InheritedFd(2)),
            daemon=True,
        )
        child.start()
        server.children.append(child)
    return child
