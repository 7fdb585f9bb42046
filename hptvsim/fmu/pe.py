"""Read what a Windows DLL (PE/COFF) exports, without loading it (and without Windows).

An FMU's ``binaries/win64/<id>.dll`` must be a 64-bit x86 PE image exporting every FMI 2.0
Co-Simulation function; :func:`read_pe` reads the headers and the export directory
(Microsoft's "PE Format" specification: DOS stub, PE signature, COFF header, PE32+ optional
header, data directory 0 = export table) so tests and ``hptvsim fmu check`` can verify that on
any machine.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Final

__all__ = ["FMI2_CS_FUNCTIONS", "PeError", "PeImage", "missing_fmi2_exports", "read_pe"]

FMI2_CS_FUNCTIONS: Final = (
    # common to Model Exchange and Co-Simulation (FMI 2.0.4, section 2.1)
    "fmi2GetTypesPlatform",
    "fmi2GetVersion",
    "fmi2SetDebugLogging",
    "fmi2Instantiate",
    "fmi2FreeInstance",
    "fmi2SetupExperiment",
    "fmi2EnterInitializationMode",
    "fmi2ExitInitializationMode",
    "fmi2Terminate",
    "fmi2Reset",
    "fmi2GetReal",
    "fmi2GetInteger",
    "fmi2GetBoolean",
    "fmi2GetString",
    "fmi2SetReal",
    "fmi2SetInteger",
    "fmi2SetBoolean",
    "fmi2SetString",
    "fmi2GetFMUstate",
    "fmi2SetFMUstate",
    "fmi2FreeFMUstate",
    "fmi2SerializedFMUstateSize",
    "fmi2SerializeFMUstate",
    "fmi2DeSerializeFMUstate",
    "fmi2GetDirectionalDerivative",
    # Co-Simulation (section 4.2)
    "fmi2SetRealInputDerivatives",
    "fmi2GetRealOutputDerivatives",
    "fmi2DoStep",
    "fmi2CancelStep",
    "fmi2GetStatus",
    "fmi2GetRealStatus",
    "fmi2GetIntegerStatus",
    "fmi2GetBooleanStatus",
    "fmi2GetStringStatus",
)
"""Every function an FMI 2.0 Co-Simulation binary exports."""

MACHINE_AMD64: Final = 0x8664
PE32_PLUS: Final = 0x20B
IMAGE_FILE_DLL: Final = 0x2000


class PeError(ValueError):
    """The bytes are not a PE image this reader understands (the message says where it stopped)."""


@dataclass(frozen=True)
class PeImage:
    """What :func:`read_pe` found.

    Attributes:
        machine: COFF machine type (``0x8664``: x86-64).
        pe32_plus: Whether the optional header is PE32+ (64-bit).
        dll: Whether the image is a DLL.
        name: The DLL's own name in its export directory.
        exports: Exported function names, sorted.
        imports: Names of the DLLs it imports from.
    """

    machine: int
    pe32_plus: bool
    dll: bool
    name: str
    exports: tuple[str, ...]
    imports: tuple[str, ...]

    @property
    def win64(self) -> bool:
        """Whether this is a 64-bit x86 DLL (what an FMU's ``binaries/win64`` must hold)."""
        return self.machine == MACHINE_AMD64 and self.pe32_plus and self.dll


def _cstr(data: bytes, offset: int) -> str:
    end = data.find(b"\0", offset)
    if offset < 0 or end < 0:
        raise PeError(f"a name at file offset {offset} runs past the end of the file")
    return data[offset:end].decode("ascii", errors="replace")


def read_pe(data: bytes) -> PeImage:
    """Parse the headers, export directory and import directory of a PE image.

    Raises:
        PeError: Not a PE image, or a header or directory points outside the file.
    """
    if len(data) < 0x40 or data[:2] != b"MZ":
        raise PeError("no MZ signature: not a Windows executable or DLL")
    (pe_offset,) = struct.unpack_from("<I", data, 0x3C)
    if data[pe_offset : pe_offset + 4] != b"PE\0\0":
        raise PeError(f"no PE signature at offset {pe_offset}")
    coff = pe_offset + 4
    machine, n_sections, _, _, _, opt_size, characteristics = struct.unpack_from("<HHIIIHH", data, coff)
    opt = coff + 20
    (magic,) = struct.unpack_from("<H", data, opt)
    if magic not in (0x10B, PE32_PLUS):
        raise PeError(f"unknown optional header magic {magic:#x}")
    dirs = opt + (112 if magic == PE32_PLUS else 96)
    (n_dirs,) = struct.unpack_from("<I", data, dirs - 4)
    sections = []
    for k in range(n_sections):
        s = opt + opt_size + 40 * k
        vsize, vaddr, raw_size, raw_ptr = struct.unpack_from("<IIII", data, s + 8)
        sections.append((vaddr, max(vsize, raw_size), raw_ptr))

    def at(rva: int) -> int:
        for vaddr, size, raw in sections:
            if vaddr <= rva < vaddr + size:
                return int(raw + rva - vaddr)
        raise PeError(f"address {rva:#x} is in no section")

    name, exports = "", []
    export_rva = struct.unpack_from("<I", data, dirs)[0] if n_dirs > 0 else 0
    if export_rva:
        e = at(export_rva)
        name_rva, _, _, n_names, _, names_rva, _ = struct.unpack_from("<IIIIIII", data, e + 12)
        name = _cstr(data, at(name_rva))
        table = at(names_rva) if n_names else 0
        exports = [_cstr(data, at(struct.unpack_from("<I", data, table + 4 * k)[0])) for k in range(n_names)]
    imports = []
    import_rva = struct.unpack_from("<I", data, dirs + 8)[0] if n_dirs > 1 else 0
    if import_rva:
        d = at(import_rva)
        while True:
            name_rva = struct.unpack_from("<I", data, d + 12)[0]
            if name_rva == 0:
                break
            imports.append(_cstr(data, at(name_rva)))
            d += 20
    return PeImage(
        machine=machine,
        pe32_plus=magic == PE32_PLUS,
        dll=bool(characteristics & IMAGE_FILE_DLL),
        name=name,
        exports=tuple(sorted(exports)),
        imports=tuple(imports),
    )


def missing_fmi2_exports(image: PeImage) -> list[str]:
    """The FMI 2.0 Co-Simulation functions the image does not export (empty when complete)."""
    have = set(image.exports)
    return [f for f in FMI2_CS_FUNCTIONS if f not in have]
