"""How many of LinuxCNC's sample configurations give a profile that loads (`ilcnc linuxcnc profile`).

    python bench/linuxcnc_profiles.py [/usr/share/doc/linuxcnc/examples/sample-configs]

Prints the counts (loaded, refused with a one-line message, failed to load) and the drive each first axis got.
"""

from __future__ import annotations

import sys
import tempfile
from collections import Counter
from pathlib import Path

from ilcnc.errors import IlcncError
from ilcnc.profile.load import load_profile
from ilcnc.shop.linuxcnc_profile import profile_from_ini


def main() -> None:
    root = Path(sys.argv[1] if len(sys.argv) > 1 else "/usr/share/doc/linuxcnc/examples/sample-configs")
    counts: Counter[str] = Counter()
    drives: Counter[str] = Counter()
    with tempfile.TemporaryDirectory() as tmp:
        for ini in sorted(root.rglob("*.ini")):
            try:
                res = profile_from_ini(ini)
            except IlcncError as exc:
                counts["refused"] += 1
                print(f"refused: {exc.format()}")
                continue
            out = Path(tmp) / "p.yaml"
            out.write_text(res.text)
            try:
                load_profile(out)
            except IlcncError as exc:
                counts["does not load"] += 1
                print(f"does not load: {ini}: {exc.format()}")
                continue
            counts["loads"] += 1
            drives[str(res.axes[0].drive)] += 1
    print(f"{sum(counts.values())} INIs: " + ", ".join(f"{k} {v}" for k, v in counts.most_common()))
    print("drive of the first axis: " + ", ".join(f"{k} {v}" for k, v in drives.most_common()))


if __name__ == "__main__":
    main()
