"""Decoder fuzz: random, truncated and corrupted frames never crash it, never yield a report that was not
sent, and are counted."""

import numpy as np

from impactsense import _core  # noqa: F401
from impactsense import _link as L


def reports(rng, n):
    return [dict(seq=i, timestamp_ms=int(rng.integers(0, 2**32)), x_mm=float(rng.uniform(0, 320)),
                 y_mm=float(rng.uniform(0, 317)), uncertainty_mm=float(rng.uniform(0, 50)),
                 energy_class=int(rng.integers(0, 2)), order=[int(v) for v in rng.permutation(4)],
                 accepted=bool(rng.integers(0, 2)), valid=True, clipped=int(rng.integers(0, 16)),
                 dead=int(rng.integers(0, 16))) for i in range(n)]


def key(r):
    return (r["seq"], r["timestamp_ms"], round(r["x_mm"], 1), round(r["y_mm"], 1), r["energy_class"],
            tuple(r["order"]), r["accepted"], r["clipped"], r["dead"])


def test_random_bytes_yield_no_frames():
    rng = np.random.default_rng(1)
    dec = L.Decoder()
    got = dec.count(rng.integers(0, 256, 2_000_000, dtype=np.uint8).tobytes())
    assert got == {"reports": 0, "other": 0}
    s = dec.stats
    assert s["bytes_skipped"] > 1_900_000


def test_random_bytes_with_sync_headers_are_counted():
    rng = np.random.default_rng(2)
    dec = L.Decoder()
    chunks = []
    for _ in range(20000):  # plausible headers followed by garbage
        chunks.append(bytes([0xA5, 0x5A, int(rng.integers(0, 3)), int(rng.choice([1, 2, 3, 7, 0x10])),
                             int(rng.integers(0, 256)), int(rng.integers(0, 5))]))
        chunks.append(rng.integers(0, 256, int(rng.integers(0, 40)), dtype=np.uint8).tobytes())
    assert dec.count(b"".join(chunks))["reports"] == 0
    s = dec.stats
    # a header of another version over garbage is a corrupt frame (its CRC fails), never counted as a frame of
    # that version
    assert s["version_errors"] == 0 and s["crc_errors"] > 0
    assert s["length_errors"] > 0 and s["type_errors"] > 0
    assert dec.errors > 10000


def test_corrupted_and_truncated_frames():
    rng = np.random.default_rng(3)
    sent = reports(rng, 5000)
    frames = [bytearray(L.encode_report(r)) for r in sent]
    intact, stream = set(), bytearray()
    n_corrupt = n_trunc = 0
    for r, f in zip(sent, frames):
        kind = rng.integers(0, 4)
        if kind == 1:  # flip 1..4 random bits anywhere
            bits = rng.choice(8 * len(f), size=int(rng.integers(1, 5)), replace=False)  # distinct bits
            for b in bits:
                f[int(b) // 8] ^= 1 << (int(b) % 8)
            n_corrupt += 1
        elif kind == 2:  # truncated
            f = f[: int(rng.integers(1, len(f)))]
            n_trunc += 1
        else:
            intact.add(key(r))
        stream += f
    dec = L.Decoder()
    got = [fr["report"] for fr in dec.feed(bytes(stream))]
    got_keys = {key(r) for r in got}
    assert got_keys <= {key(r) for r in sent}  # nothing invented
    # every report whose bytes arrived unharmed and not swallowed by a preceding truncated frame
    assert len(got_keys & intact) >= 0.9 * len(intact)
    corrupted_seen = {key(r) for r in got} - intact
    assert not corrupted_seen  # a corrupted report is never emitted
    assert dec.errors > 0.5 * n_corrupt


def test_crafted_bodies_with_valid_crc_are_not_reports():
    # correct CRC but malformed report bodies (ToA order not a permutation, reserved bits, wrong length)
    good = bytearray(L.report_body(reports(np.random.default_rng(4), 1)[0]))
    bad_order = bytearray(good)
    bad_order[15] = 0  # order 0,0,0,0
    bad_status = bytearray(good)
    bad_status[16] |= 0x80
    dec = L.Decoder()
    out = dec.feed(L.encode_frame(L.TYPE_REPORT, bytes(bad_order)) + L.encode_frame(L.TYPE_REPORT, bytes(bad_status))
                   + L.encode_frame(L.TYPE_REPORT, bytes(good[:-1])) + L.encode_frame(L.TYPE_REPORT, bytes(good)))
    assert [f["kind"] for f in out] == ["report"]
    s = dec.stats
    assert s["payload_errors"] == 2 and s["length_errors"] >= 1


def test_split_delivery_is_byte_exact():
    rng = np.random.default_rng(5)
    sent = reports(rng, 300)
    stream = b"".join(L.encode_report(r) for r in sent)
    dec = L.Decoder()
    got, i = [], 0
    while i < len(stream):
        n = int(rng.integers(1, 64))
        got += [f["report"]["seq"] for f in dec.feed(stream[i:i + n])]
        i += n
    assert got == list(range(300)) and dec.errors == 0
