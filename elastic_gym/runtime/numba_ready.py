"""Imported last by a fork server (`elastic_gym.runtime.fork_server`): numba's compiler
readied in the server, so that each worker forked from it does not ready it again.

numba installs its typing and lowering registries (those of every module imported so far)
the first time a process compiles a kernel or loads one from its cache: about a third of
a second, more than loading a kernel. Done here once, after the server's other imports,
every forked worker inherits them; a module imported later adds only its own.
"""

from numba.core.registry import cpu_target

cpu_target.target_context.refresh()  # its typing context's too
