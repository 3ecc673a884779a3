"""Zip archives crafted for the bounded-unpacking tests (SSP packages, FMUs)."""

import struct
import zipfile
from pathlib import Path

MiB = 1 << 20


def zeros_archive(path, size, name, others):
    """An archive with the entries ``others`` (name -> bytes) and an entry ``name`` of
    ``size`` bytes of zeros, deflated and written in chunks (64 MiB of zeros make a
    64 KiB archive)."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as out:
        for other, data in others.items():
            out.writestr(other, data)
        with out.open(name, "w", force_zip64=size >= 0xFFFFFFFF) as entry:
            zeros = bytes(MiB)
            for _ in range(size // MiB):
                entry.write(zeros)
    return Path(path)


def set_declared_size(path, name, file_size):
    """Rewrite the uncompressed size entry ``name`` declares, in its local header and in
    its central directory record (its data and CRC stay as they are)."""
    data = bytearray(Path(path).read_bytes())
    encoded = name.encode()
    found = 0
    # (signature, offset of the size field, of the name length, of the name)
    for signature, field, length_at, name_at in ((b"PK\x03\x04", 22, 26, 30),
                                                 (b"PK\x01\x02", 24, 28, 46)):
        start = 0
        while (at := data.find(signature, start)) >= 0:
            length = struct.unpack_from("<H", data, at + length_at)[0]
            if bytes(data[at + name_at:at + name_at + length]) == encoded:
                struct.pack_into("<I", data, at + field, file_size)
                found += 1
            start = at + 4
    assert found == 2, f"{name}: {found} headers found, 2 expected"
    Path(path).write_bytes(bytes(data))
