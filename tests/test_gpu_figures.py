"""The staging that takes issue 43's measurements to a GPU machine without our packages
(lab/bench/gpu_figures.py): Warp's fatbin cut to one architecture, and a compressed file split
across two calls and joined again (or refused in one line when its first part is gone)."""

import lzma
import struct

import pytest

from lab.bench.gpu_figures import FATBIN_MAGIC, install, keep_one_arch, split_for_two_calls


def elf_with_fatbin(entries: list[tuple[int, int, bytes]]) -> bytes:
    """A minimal ELF64 whose only sections are ``.nv_fatbin`` (one fatbin of ``entries``: kind,
    sm, payload) and the section names."""
    body = b"".join(
        struct.pack("<HHIIIIIIIQQ", kind, 0, 48, len(p), 0, len(p), 0, 0, sm, 0, 0) + p for kind, sm, p in entries
    )
    fatbin = struct.pack("<IHHQ", FATBIN_MAGIC, 1, 16, len(body)) + body
    names = b"\0.nv_fatbin\0.shstrtab\0"
    fat_at, names_at = 64, 64 + len(fatbin)
    shoff = names_at + len(names)
    header = bytearray(64)
    struct.pack_into("<Q", header, 0x28, shoff)
    struct.pack_into("<HHH", header, 0x3A, 64, 3, 2)
    sections = bytes(64)  # the null section
    sections += struct.pack("<IIQQQQIIQQ", 1, 1, 0, 0, fat_at, len(fatbin), 0, 0, 8, 0)
    sections += struct.pack("<IIQQQQIIQQ", 12, 3, 0, 0, names_at, len(names), 0, 0, 1, 0)
    return bytes(header) + fatbin + names + sections


def test_only_the_kept_architecture_and_the_lowest_ptx_survive():
    entries = [(2, 75, b"a" * 32), (2, 90, b"b" * 32), (1, 75, b"c" * 16), (1, 121, b"d" * 16)]
    trimmed, zeroed = keep_one_arch(elf_with_fatbin(entries))
    assert zeroed == 32 + 16
    assert b"b" * 32 in trimmed and b"c" * 16 in trimmed
    assert b"a" * 32 not in trimmed and b"d" * 16 not in trimmed
    with pytest.raises(ValueError, match="no sm_90"):
        keep_one_arch(elf_with_fatbin([(2, 80, b"a" * 32)]))


def test_a_file_split_across_two_calls_is_joined_or_refused_in_one_line(tmp_path):
    staged = tmp_path / "staged"
    for sub in ("cmdp_rl", "configs", "lab", "experiments", "whl"):
        (staged / sub).mkdir(parents=True)
    library = bytes(range(256)) * 400
    (staged / "payload" / "warp" / "bin").mkdir(parents=True)
    (staged / "payload" / "warp" / "bin" / "warp.so.xz").write_bytes(lzma.compress(library))
    split_for_two_calls(staged, tmp_path / "one", tmp_path / "two", first_bytes=100)
    assert (tmp_path / "one" / "parts" / "warp" / "bin" / "warp.so.xz.part1").stat().st_size == 100
    assert not (tmp_path / "two" / "payload" / "warp" / "bin" / "warp.so.xz").exists()

    site = tmp_path / "site"
    report = install(tmp_path / "two" / "whl", tmp_path / "two" / "payload", site, tmp_path / "one" / "parts")
    assert "problem" not in report
    assert (site / "warp" / "bin" / "warp.so").read_bytes() == library
    report = install(tmp_path / "two" / "whl", tmp_path / "two" / "payload", tmp_path / "bare", tmp_path / "gone")
    assert "the first call's part of warp/bin/warp.so.xz is gone" in report["problem"]
