"""sigrok-cli's CAN decoder (Debian package sigrok-cli) as a reference
reader of the frame model's bits: the bits are sampled at
:data:`SAMPLES_PER_BIT` samples per bit into a ``-I binary`` capture and
decoded by ``-P can``; each frame's identifier, DLC, data, CRC and stuff
bits come back as the decoder printed them."""

from __future__ import annotations

import re
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

import pytest

from service_kit.can_wire.bits import FrameBits

SAMPLES_PER_BIT = 10
GAP_BITS = 20

needs_sigrok = pytest.mark.skipif(shutil.which("sigrok-cli") is None, reason="sigrok-cli not installed (Debian package sigrok-cli)")


@dataclass(frozen=True)
class Decoded:
    text: str
    identifier: int
    extended: bool
    remote: bool
    dlc: int
    data: bytes
    crc: int
    stuff_positions: tuple[int, ...]


def decode(frames: list[FrameBits], bitrate: int, tmp_path: Path) -> list[Decoded]:
    samples = bytearray([1] * SAMPLES_PER_BIT * GAP_BITS)
    starts = []
    for frame in frames:
        starts.append(len(samples))
        samples += bytes(b for b in frame.bits for _ in range(SAMPLES_PER_BIT))
        samples += bytes([1] * SAMPLES_PER_BIT * GAP_BITS)
    path = tmp_path / "frames.bin"
    path.write_bytes(bytes(samples))
    base = ["sigrok-cli", "-I", f"binary:numchannels=1:samplerate={bitrate * SAMPLES_PER_BIT}", "-i", str(path)]
    base += ["-P", f"can:can_rx=0:nominal_bitrate={bitrate}"]
    fields = subprocess.run([*base, "-A", "can=fields:warnings"], capture_output=True, text=True, timeout=120, check=True).stdout
    stuffs = subprocess.run([*base, "-A", "can=stuff-bit", "--protocol-decoder-samplenum"], capture_output=True, text=True, timeout=120, check=True).stdout
    assert "warning" not in fields.lower() and "must" not in fields.lower(), fields
    texts = fields.split("can-1: Start of frame")[1:]
    assert len(texts) == len(frames), fields
    stuff_samples = [int(m.group(1)) for m in re.finditer(r"^(\d+)-\d+ can-1:", stuffs, re.M)]
    out = []
    for text, start, frame in zip(texts, starts, frames):
        extended = "extended frame" in text
        ident = re.search(r"Full Identifier: (\d+)" if extended else r"Identifier: (\d+)", text)
        dlc = re.search(r"Data length code: (\d+)", text)
        crc = re.search(r"CRC-15 sequence: 0x([0-9a-f]+)", text)
        assert ident and dlc and crc, text
        end = start + frame.n_bits * SAMPLES_PER_BIT
        out.append(
            Decoded(
                text=text,
                identifier=int(ident.group(1)),
                extended=extended,
                remote="Remote transmission request: remote frame" in text,
                dlc=int(dlc.group(1)),
                data=bytes(int(b, 16) for b in re.findall(r"Data byte \d+: 0x([0-9a-f]{2})", text)),
                crc=int(crc.group(1), 16),
                stuff_positions=tuple((s - start) // SAMPLES_PER_BIT for s in stuff_samples if start <= s < end),
            )
        )
    return out
