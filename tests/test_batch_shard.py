"""``staggered batch --shard I/N``: N disjoint parts of the file list that
cover it, the same on every machine (issue 17, item 5)."""

from __future__ import annotations

import hashlib
import os
import shutil

import pytest
from click.testing import CliRunner

from staggered_cli import batching as B
from staggered_cli.cli.main import cli
from staggered_cli.errors import UsageError

from .conftest import mocap, one_line_error

NAMES = [
    "a.bvh",
    "B.BVH",
    "walk.c3d",
    "sub dir/cmu_02_01_walk.bvh",
    "sub dir/deeper/idle.bvh",
    "ünï/コード.c3d",
    *(f"library/s{s:02d}/take_{t}.bvh" for s in range(12) for t in range(9)),
]


def _tree(root, names=NAMES):
    for rel in names:
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(b"")  # planning reads no file
    (root / "notes.txt").write_text("not an input\n")
    return root


def _planned(lib, out, shard=None) -> list[str]:
    todo, skipped = B.plan(str(lib), str(out), shard=shard)
    return [job.rel for job in todo] + [r.rel for r in skipped]


@pytest.mark.parametrize("n", [1, 2, 3, 5, 8, 13])
def test_shards_cover_every_file_exactly_once(tmp_path, n):
    lib = _tree(tmp_path / "in")
    every = _planned(lib, tmp_path / "out")
    assert sorted(every) == sorted(NAMES)
    parts = [_planned(lib, tmp_path / "out", (i, n)) for i in range(1, n + 1)]
    flat = [rel for part in parts for rel in part]
    assert sorted(flat) == sorted(every)  # each file in one part, none twice
    assert len(set(flat)) == len(flat)
    if n <= 8:  # 114 files: a hash spreads them over every part
        assert all(part for part in parts)


def test_shards_are_the_same_whatever_the_listing_order(tmp_path):
    # two libraries with the same names, created in opposite orders (so their
    # directory entries are listed differently) get the same parts
    one = _tree(tmp_path / "one")
    two = _tree(tmp_path / "two", list(reversed(NAMES)))
    for i in (1, 2, 3):
        assert _planned(one, tmp_path / "o1", (i, 3)) == _planned(two, tmp_path / "o2", (i, 3))


def test_shard_of_is_a_hash_of_the_relative_path():
    # pinned: a change of the partition would split a running farm's library differently
    assert [B.shard_of("cmu_01_01_forward_jumps.bvh", n) for n in (1, 2, 3, 8, 100)] == [1, 2, 2, 4, 56]
    assert [B.shard_of("copy0/cmu_01_01_forward_jumps.bvh", n) for n in (1, 2, 3, 8, 100)] == [1, 2, 1, 8, 88]
    assert [B.shard_of("ünï/コード.c3d", n) for n in (1, 2, 3, 8, 100)] == [1, 2, 1, 2, 38]
    rel = "sub dir/Walk.BVH"
    expected = int.from_bytes(hashlib.sha256(rel.encode()).digest()[:8], "big") % 7 + 1
    assert B.shard_of(rel, 7) == expected
    assert B.shard_of(rel.replace("/", os.sep), 7) == expected  # the separator does not matter


def test_adding_a_file_moves_no_other(tmp_path):
    lib = _tree(tmp_path / "in")
    before = {i: _planned(lib, tmp_path / "out", (i, 4)) for i in range(1, 5)}
    (lib / "library" / "s00" / "take_new.bvh").write_bytes(b"")
    after = {i: _planned(lib, tmp_path / "out", (i, 4)) for i in range(1, 5)}
    added = [i for i in after if after[i] != before[i]]
    assert len(added) == 1
    assert sorted(set(after[added[0]]) - set(before[added[0]])) == ["library/s00/take_new.bvh"]


@pytest.mark.parametrize(
    "text, expected",
    [("3/8", (3, 8)), ("1/1", (1, 1)), ("8/8", (8, 8)), (" 2 / 3 ", (2, 3)), ("007/010", (7, 10))],
)
def test_parse_shard(text, expected):
    assert B.parse_shard(text) == expected


@pytest.mark.parametrize(
    "text, words",
    [
        ("0/0", "N (the number of parts) must be at least 1"),
        ("1/0", "N (the number of parts) must be at least 1"),
        ("5/4", "I must be between 1 and 4 (parts are numbered from 1)"),
        ("0/4", "I must be between 1 and 4"),
        ("x", "expected I/N, e.g. 3/8"),
        ("3", "expected I/N"),
        ("3/8/1", "expected I/N"),
        ("-1/3", "expected I/N"),
        ("1.5/3", "expected I/N"),
        ("³/8", "expected I/N"),
        ("", "expected I/N"),
        ("1/9999999999", "expected I/N"),
    ],
)
def test_bad_shards_are_one_line_usage_errors(tmp_path, text, words):
    with pytest.raises(UsageError, match="^shard "):  # the library names its argument
        B.parse_shard(text)
    lib = tmp_path / "in"
    lib.mkdir()
    r = CliRunner().invoke(cli, ["batch", str(lib), str(tmp_path / "out"), "--shard", text], catch_exceptions=False)
    one_line_error(r, 2, "--shard", words)
    assert not (tmp_path / "out").exists()


def test_shards_bake_the_library_once(tmp_path):
    lib = tmp_path / "in"
    names = {
        "a/run.bvh": "bandai2_run_normal_001.bvh",
        "a/bow.bvh": "bandai1_bow_normal_001.bvh",
        "b/idle.bvh": "games105_idle.bvh",
        "b/run.bvh": "bandai2_run_normal_001.bvh",
    }
    for rel, name in names.items():
        (lib / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(mocap(name), lib / rel)
    out = tmp_path / "out"
    done: list[str] = []
    for i in (1, 2):
        r = CliRunner().invoke(
            cli, ["batch", str(lib), str(out), "--shard", f"{i}/2", "--jobs", "1"], catch_exceptions=False
        )
        assert r.exit_code == 0, r.output
        rows = [line.split()[0] for line in r.stdout.splitlines()[1:-1]]
        assert rows == sorted(rel for rel in names if B.shard_of(rel, 2) == i)
        assert f"(shard {i}/2): 0 built, {len(rows)} unchanged, 0 skipped, 0 failed" in r.stdout
        done += rows
    assert sorted(done) == sorted(names)
    assert sorted(str(p.relative_to(out)) for p in out.rglob("*.bvh")) == sorted(names)
