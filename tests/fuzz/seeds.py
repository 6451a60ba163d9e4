"""Writes the seed corpus tests/fuzz/corpus/<target>/ (committed; run again after changing fmi_fuzz.c's encoding):

    python -m tests.fuzz.seeds

Each seed is a legal run in fmi_fuzz.c's encoding (the fuzzer mutates from there): Co-Simulation (initialize,
read everything, steps, FMU state round trips, directional derivatives, input derivatives) and Model Exchange
(initialize, event and continuous-time modes, states set near the present ones, every getter)."""
from __future__ import annotations

import struct

from .targets import CORPUS, TARGETS


def raw(x: float) -> bytes:
    """fmi_fuzz.c's value(): 8 raw bytes, big-endian bits."""
    return bytes([0]) + struct.pack(">d", x)


def near(k: int = 128) -> bytes:
    """value(): the variable's last value times 1 + (k - 128)/256."""
    return bytes([100, k])


def every(n: int = 40) -> bytes:
    """refs(): value references 0 .. n-1 (the harness takes them modulo the FMU's count + 1)."""
    return bytes([n, *range(n)])


def co_simulation(h: float) -> bytes:
    head = bytes([1 | 4])
    body = bytes([9, 30, 3]) + every()
    body += bytes([0]) + every(12) + b"".join(near(130) for _ in range(12))
    for _ in range(3):
        body += bytes([10]) + raw(h) + bytes([1]) + bytes([30])
    body += bytes([22, 0, 0, 23, 0, 0, 22, 1, 0, 23, 1, 3]) + b"".join(bytes([0, 0, 0, 8 * i, 0, 255]) for i in range(3))
    body += bytes([0, 0])
    body += bytes([12]) + every(8) + every(8) + b"".join(raw(1.0) for _ in range(8))
    body += bytes([13, 4, 0, 1, 2, 3]) + b"".join(bytes([2]) + raw(0.5) for _ in range(4))
    body += bytes([10]) + raw(h) + bytes([1]) + bytes([14, 8, *range(8), *([2] * 8)])
    body += bytes([27, 0, 0, 22, 0, 1, 26, 25, 29, 30])
    return head + body


def model_exchange() -> bytes:
    head = bytes([0 | 4 | 2])
    body = bytes([9, 19, 20, 17, 30])
    for t in (1e-4, 2e-4):
        body += bytes([15]) + raw(t) + bytes([16]) + bytes([0, 140] * 8) + bytes([17, 21, 0])
    body += bytes([12]) + every(10) + every(10) + b"".join(raw(1.0) for _ in range(10))
    body += bytes([22, 0, 0, 23, 0, 0, 18, 19, 20, 22, 0, 1, 17, 26, 17])
    return head + body


def main() -> None:
    for target in TARGETS:
        folder = CORPUS / target
        folder.mkdir(parents=True, exist_ok=True)
        seeds = {"cs_short": co_simulation(1e-6), "cs_long": co_simulation(1e-2), "me": model_exchange(),
                 "cs_refused": bytes([1, 10, 0, 30, 8, 26])}
        for name, data in seeds.items():
            (folder / name).write_bytes(data)


if __name__ == "__main__":
    main()
