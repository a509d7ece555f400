"""Run many ``pointillist`` command lines in one process (tests/test_hostile.py).

Usage: ``python _hostile_driver.py CASES.json RESULTS.jsonl``. CASES is a list of
``{"id": str, "argv": [str, ...]}``; for each, :func:`pointillist.cli.main` runs with file
descriptors 1 and 2 captured (so that what C++ libraries print is seen too), and one JSON line
``{"id", "rc", "stdout", "stderr", "seconds"}`` is appended to RESULTS as soon as the case ends
(a hang or an abort leaves the cases before it recorded). An exception escaping ``main`` is
recorded as ``rc = "escaped: <repr>"`` with its traceback in ``stderr``.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
import traceback


def _run(argv: list[str]) -> tuple[object, str, str]:
    from pointillist.cli import main

    sys.stdout.flush()
    sys.stderr.flush()
    saved = [(fd, os.dup(fd), tempfile.TemporaryFile()) for fd in (1, 2)]
    for fd, _, capture in saved:
        os.dup2(capture.fileno(), fd)
    try:
        try:
            rc: object = main(argv)
        except SystemExit as exit_:  # argparse
            rc = exit_.code if isinstance(exit_.code, int) else 2
        except BaseException as error:  # noqa: BLE001 - recorded, the test fails on it
            rc = f"escaped: {error!r}"
            traceback.print_exc()
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        texts = []
        for fd, old, capture in saved:
            os.dup2(old, fd)
            os.close(old)
            capture.seek(0)
            texts.append(capture.read().decode(errors="replace"))
            capture.close()
    return rc, texts[0], texts[1]


def main() -> None:
    cases_path, results_path = sys.argv[1:3]
    with open(cases_path) as handle:
        cases = json.load(handle)
    with open(results_path, "a") as results:
        for case in cases:
            results.write(json.dumps({"id": case["id"], "started": True}) + "\n")
            results.flush()
            start = time.perf_counter()
            rc, out, err = _run(case["argv"])
            results.write(json.dumps({"id": case["id"], "rc": rc, "stdout": out, "stderr": err,
                                      "seconds": time.perf_counter() - start}) + "\n")
            results.flush()


if __name__ == "__main__":
    main()
