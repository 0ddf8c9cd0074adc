"""A CiA 301 SDO server as a pure function of request payloads.

:meth:`SdoServer.handle` takes the 8 data bytes of a client request (COB-ID
0x600 + node) and returns the 8-byte response for 0x580 + node, or ``None``
when the protocol calls for silence (a client abort). Supported:

* expedited upload and download (1-4 bytes, with or without size indicated);
* segmented upload (values longer than 4 bytes: strings such as 0x1008) and
  segmented download (up to :data:`MAX_SEGMENTED_DOWNLOAD` bytes), with
  toggle-bit checking;
* block transfers are refused with abort 0x05040001 (the client falls back).

Access, type and range errors from the :class:`ObjectDictionary` become
abort frames with the matching CiA 301 code. A new initiate request while a
segmented transfer is open abandons that transfer (as after a client
timeout).
"""

from __future__ import annotations

import logging
import struct
from collections import Counter
from dataclasses import dataclass, field
from typing import Final

from plant_emulator.canopen_node.od import ObjectDictionary, SdoAbort, SdoAbortCode

log = logging.getLogger(__name__)

MAX_SEGMENTED_DOWNLOAD: Final[int] = 256

_HEADER = struct.Struct("<BHB")
_ABORT = struct.Struct("<BHBI")

# command specifiers (bits 7..5 of byte 0)
CCS_DOWNLOAD_SEGMENT: Final[int] = 0
CCS_INITIATE_DOWNLOAD: Final[int] = 1
CCS_INITIATE_UPLOAD: Final[int] = 2
CCS_UPLOAD_SEGMENT: Final[int] = 3
CCS_ABORT: Final[int] = 4
CCS_BLOCK_UPLOAD: Final[int] = 5
CCS_BLOCK_DOWNLOAD: Final[int] = 6

SCS_UPLOAD_SEGMENT: Final[int] = 0x00
SCS_DOWNLOAD_SEGMENT: Final[int] = 0x20
SCS_INITIATE_UPLOAD: Final[int] = 0x40
SCS_INITIATE_DOWNLOAD: Final[int] = 0x60
ABORT: Final[int] = 0x80

TOGGLE: Final[int] = 0x10


@dataclass
class SdoCounters:
    uploads: int = 0
    """completed uploads (reads)"""
    downloads: int = 0
    """completed downloads (writes)"""
    aborts: Counter[int] = field(default_factory=Counter)
    """aborts sent, by abort code"""
    client_aborts: int = 0


@dataclass
class _Transfer:
    upload: bool
    index: int
    sub: int
    data: bytearray
    size: int | None = None
    toggle: int = 0


def abort_frame(index: int, sub: int, code: int) -> bytes:
    return _ABORT.pack(ABORT, index & 0xFFFF, sub & 0xFF, code & 0xFFFFFFFF)


class SdoServer:
    """One SDO server channel (the default SDO of the node)."""

    def __init__(self, od: ObjectDictionary) -> None:
        self.od = od
        self.counters = SdoCounters()
        self._transfer: _Transfer | None = None

    def reset(self) -> None:
        """Drop any open segmented transfer (NMT reset)."""
        self._transfer = None

    @property
    def busy(self) -> bool:
        return self._transfer is not None

    def handle(self, request: bytes | bytearray) -> bytes | None:
        if len(request) != 8:
            raise ValueError("SDO requests are 8 bytes")  # the node counts these before calling
        req = bytes(request)
        ccs = req[0] >> 5
        index, sub = struct.unpack_from("<HB", req, 1)
        try:
            if ccs == CCS_INITIATE_UPLOAD:
                return self._initiate_upload(index, sub)
            if ccs == CCS_UPLOAD_SEGMENT:
                return self._upload_segment(req)
            if ccs == CCS_INITIATE_DOWNLOAD:
                return self._initiate_download(req, index, sub)
            if ccs == CCS_DOWNLOAD_SEGMENT:
                return self._download_segment(req)
            if ccs == CCS_ABORT:
                self._transfer = None
                self.counters.client_aborts += 1
                return None
            raise SdoAbort(SdoAbortCode.INVALID_COMMAND, f"command specifier {ccs} not supported")
        except Exception as exc:  # noqa: BLE001 - a server never dies of one request
            if isinstance(exc, SdoAbort):
                e = exc
            else:
                log.exception("SDO request %s failed inside the server", req.hex())
                e = SdoAbort(SdoAbortCode.GENERAL_ERROR, str(exc))
            t = self._transfer
            if ccs in (CCS_UPLOAD_SEGMENT, CCS_DOWNLOAD_SEGMENT) and t is not None:
                index, sub = t.index, t.sub
            elif ccs in (CCS_UPLOAD_SEGMENT, CCS_DOWNLOAD_SEGMENT):
                index, sub = 0, 0
            self._transfer = None
            self.counters.aborts[e.code] += 1
            return abort_frame(index, sub, e.code)

    # --- upload ----------------------------------------------------------------

    def _initiate_upload(self, index: int, sub: int) -> bytes:
        self._transfer = None
        data = self.od.read(index, sub)
        if len(data) <= 4:
            n = 4 - len(data)
            self.counters.uploads += 1
            return _HEADER.pack(SCS_INITIATE_UPLOAD | (n << 2) | 0x03, index, sub) + data.ljust(4, b"\x00")
        self._transfer = _Transfer(upload=True, index=index, sub=sub, data=bytearray(data))
        return _HEADER.pack(SCS_INITIATE_UPLOAD | 0x01, index, sub) + struct.pack("<I", len(data))

    def _upload_segment(self, req: bytes) -> bytes:
        t = self._transfer
        if t is None or not t.upload:
            raise SdoAbort(SdoAbortCode.INVALID_COMMAND, "upload segment without an upload in progress")
        toggle = req[0] & TOGGLE
        if toggle != t.toggle:
            raise SdoAbort(SdoAbortCode.TOGGLE_NOT_ALTERNATED)
        chunk = bytes(t.data[:7])
        del t.data[:7]
        last = not t.data
        n = 7 - len(chunk)
        response = bytes([SCS_UPLOAD_SEGMENT | toggle | (n << 1) | int(last)]) + chunk.ljust(7, b"\x00")
        t.toggle ^= TOGGLE
        if last:
            self._transfer = None
            self.counters.uploads += 1
        return response

    # --- download --------------------------------------------------------------

    def _initiate_download(self, req: bytes, index: int, sub: int) -> bytes:
        self._transfer = None
        expedited = bool(req[0] & 0x02)
        size_indicated = bool(req[0] & 0x01)
        if expedited:
            data = req[4 : 8 - ((req[0] >> 2) & 0x3)] if size_indicated else req[4:8]
            e = self.od.check_writable(index, sub)
            if not size_indicated and e.dtype.size is not None:
                data = data[: e.dtype.size]  # size not indicated: the object's own size
            self.od.write(index, sub, data)
            self.counters.downloads += 1
            return _HEADER.pack(SCS_INITIATE_DOWNLOAD, index, sub) + b"\x00" * 4
        e = self.od.check_writable(index, sub)
        size: int | None = None
        if size_indicated:
            (size,) = struct.unpack_from("<I", req, 4)
            if size > MAX_SEGMENTED_DOWNLOAD:
                raise SdoAbort(SdoAbortCode.OUT_OF_MEMORY, f"{size} bytes is more than this server accepts")
            if e.dtype.size is not None and size != e.dtype.size:
                code = SdoAbortCode.LENGTH_TOO_HIGH if size > e.dtype.size else SdoAbortCode.LENGTH_TOO_LOW
                raise SdoAbort(code, f"{e.dtype.name} takes {e.dtype.size} bytes, not {size}")
        self._transfer = _Transfer(upload=False, index=index, sub=sub, data=bytearray(), size=size)
        return _HEADER.pack(SCS_INITIATE_DOWNLOAD, index, sub) + b"\x00" * 4

    def _download_segment(self, req: bytes) -> bytes:
        t = self._transfer
        if t is None or t.upload:
            raise SdoAbort(SdoAbortCode.INVALID_COMMAND, "download segment without a download in progress")
        toggle = req[0] & TOGGLE
        if toggle != t.toggle:
            raise SdoAbort(SdoAbortCode.TOGGLE_NOT_ALTERNATED)
        n = (req[0] >> 1) & 0x7
        t.data += req[1 : 8 - n]
        if len(t.data) > MAX_SEGMENTED_DOWNLOAD:
            raise SdoAbort(SdoAbortCode.OUT_OF_MEMORY)
        t.toggle ^= TOGGLE
        if req[0] & 0x01:  # last segment
            if t.size is not None and len(t.data) != t.size:
                raise SdoAbort(SdoAbortCode.LENGTH_MISMATCH, f"announced {t.size} bytes, received {len(t.data)}")
            self.od.write(t.index, t.sub, bytes(t.data))
            self._transfer = None
            self.counters.downloads += 1
        return bytes([SCS_DOWNLOAD_SEGMENT | toggle]) + b"\x00" * 7
