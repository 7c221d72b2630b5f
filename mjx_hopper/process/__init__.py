"""The process floor, the lowest: what a run needs of its process and of the processes beside it.

`distributed` joins a run over several processes (JAX's distributed runtime), `stop` turns Ctrl-C,
SIGTERM or a request from code into a save and a stop, `runlock` keeps one writer per run folder,
`jax_private` is the private JAX API in use, with the versions it was checked on, `errors`
writes an error as one line, `ledger` records what a process compiles, `parallel` lays arrays
over the process's devices (meshes, shardings, its cores), and `runtime` is `mjx_hopper.setup`,
all that is set process-wide.
"""
