"""`edgedsm bench sim` runs end to end on a tiny size and writes its markdown report."""

from __future__ import annotations

import re

from edgedsm.cli import main


def test_bench_sim_quick_writes_the_tables(tmp_path, capsys):
    out = tmp_path / "bench.md"
    code = main(["bench", "sim", "--quick", "--sizes", "32", "--repeats", "1", "--frames", "2",
                 "--accuracy-frames", "8", "--output", str(out)])
    assert code == 0
    text = out.read_text(encoding="utf-8")
    for heading in ("## Frames per second by effect", "## complex64 against complex128",
                    "## Peer: pyspeckle", "| base: surface + activity", "| all effects", "| S3 |"):
        assert heading in text
    assert re.search(r"Other work took \d+\.\d% of the machine's CPU time during the timing", text)
    assert text in capsys.readouterr().out + "\n"  # printed as well as written
