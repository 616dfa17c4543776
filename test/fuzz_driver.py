"""Runs the command-line tools on many hostile inputs in one process and reports each case.

Usage: ``python fuzz_driver.py CASES.json RESULTS.json``. ``CASES.json`` holds
``{"watched": [folders nothing may open], "inputs": [folders nothing may write],
"cases": [{"id", "tool", "argv"}, ...]}``. For each case the tool's ``main(argv)``
runs as the console script would, and the driver records the exit status, the
lines written to stderr, a traceback if an exception escaped ``main``, every
warning raised (each time, not once per place as Python prints them), every
file opened inside a watched folder (links resolved) and every input file
opened for writing (through the interpreter's audit hook on ``open``). At the
end it records the process's peak resident memory. Used by
``test_hostile_input.py``; a separate process so that memory is measured for
these cases alone and a crash cannot take the test session with it.
"""

import contextlib
import io
import json
import os
import resource
import sys
import traceback
import warnings

TOOLS = {"reconstruct": "sfs_ros.cli.reconstruct", "export": "sfs_ros.cli.export",
         "calibrate": "sfs_ros.cli.calibrate"}


def _under(path: str, roots: list[str]) -> bool:
    return any(path == root or path.startswith(root + os.sep) for root in roots)


def main() -> None:
    spec = json.loads(open(sys.argv[1]).read())
    watched = [os.path.realpath(p) for p in spec["watched"]]
    inputs = [os.path.realpath(p) for p in spec["inputs"]]
    opened: list[str] = []

    def audit(event, args):
        if event != "open" or not isinstance(args[0], (str, bytes, os.PathLike)):
            return
        path = os.path.realpath(os.fsdecode(args[0]))
        mode, flags = args[1], args[2] if len(args) > 2 else 0
        writes = (mode is not None and any(c in mode for c in "wax+")) or \
            (mode is None and flags & (os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_TRUNC))
        if _under(path, watched):
            opened.append(f"opened {path}")
        elif writes and _under(path, inputs):
            opened.append(f"wrote {path}")

    sys.addaudithook(audit)
    import importlib

    results = []
    for case in spec["cases"]:
        main_fn = importlib.import_module(TOOLS[case["tool"]]).main
        opened.clear()
        err, out = io.StringIO(), io.StringIO()
        escaped = None
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out), \
                warnings.catch_warnings(record=True) as warned:
            warnings.simplefilter("always")       # those Python shows, each time
            for hidden in (DeprecationWarning, PendingDeprecationWarning, ImportWarning,
                           ResourceWarning):
                warnings.filterwarnings("ignore", category=hidden)
            try:
                status = main_fn(case["argv"])
            except SystemExit as exit_:  # argparse
                status = exit_.code if isinstance(exit_.code, int) else 2
            except BaseException:  # noqa: BLE001 - recorded, this is what the test looks for
                status, escaped = None, traceback.format_exc()
        results.append({"id": case["id"], "status": status, "stderr": err.getvalue(),
                        "traceback": escaped, "opened": list(opened),
                        "warnings": [f"{w.category.__name__}: {w.message} ({w.filename}:"
                                     f"{w.lineno})" for w in warned]})
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    with open(sys.argv[2], "w") as f:
        json.dump({"results": results, "peak_rss_mib": peak_mib}, f)


if __name__ == "__main__":
    main()
