"""The benchmarks, one module each with `run() -> dict` (`python -m evaluation.bench [NAME ...]`,
`make bench BENCH=NAME`; the runner is `__main__.py`).

Dr.Jit, and every sgdr module that imports it, are imported inside the benchmarks' functions,
after `sgdr.backend.init`: Dr.Jit reads `DRJIT_LIBLLVM_PATH`, which `init` sets, when it is
first imported. (`diagnose` is the exception: it composes the config, which imports Dr.Jit,
to learn which backend to choose.)
"""
