"""``core.cpu`` reads the processor's flags; ``grip.frozen.resolve_precision`` turns
``--precision auto`` into the precision the hardware runs natively and warns about
emulated bf16. The decision is tested on made-up processors, so it runs on any machine."""

from __future__ import annotations

import pytest

from grip_bench.core.cpu import cpu_info, info_from, parse_cpuinfo
from grip_bench.grip.frozen import PRECISION_CHOICES, resolve_precision

SAPPHIRE = info_from("Intel(R) Xeon(R) Platinum 8480+",
                     {"avx2", "fma", "avx512f", "avx512_bf16", "amx_tile", "amx_bf16",
                      "amx_int8", "avx512_vnni", "sse4_2"}, "AVX512")
EPYC_AVX2 = info_from("AMD EPYC 7B12", {"avx2", "fma", "sse4_2"}, "AVX2")

X86 = """processor\t: 0
vendor_id\t: GenuineIntel
model name\t: Intel(R) Xeon(R) Processor
flags\t\t: fpu sse avx2 fma avx512f avx512_bf16 amx_tile amx_bf16 avx512_vnni
processor\t: 1
model name\t: other
flags\t\t: fpu
"""
ARM = """processor\t: 0
BogoMIPS\t: 50.00
Features\t: fp asimd evtstrm aes sha1 crc32 bf16 i8mm sve
CPU implementer\t: 0x41
"""


def test_parse_cpuinfo_reads_the_first_processor():
    model, flags = parse_cpuinfo(X86)
    assert model == "Intel(R) Xeon(R) Processor"
    assert {"avx512_bf16", "amx_bf16", "avx2"} <= flags and "sse" in flags
    info = info_from(model, flags, "AVX512")
    assert info.native_bf16 and info.native_int8
    assert "sse" not in info.flags  # only the flags that decide GEMM speed are kept


def test_parse_cpuinfo_arm_features():
    _, flags = parse_cpuinfo(ARM)
    info = info_from("", flags, "DEFAULT")
    assert info.native_bf16 and info.native_int8 and info.flags == ("asimd", "bf16", "i8mm",
                                                                     "sve")
    assert info.model  # falls back to the platform's name, never empty


def test_avx2_only_has_no_native_bf16():
    assert not EPYC_AVX2.native_bf16 and not EPYC_AVX2.native_int8
    assert SAPPHIRE.native_bf16 and SAPPHIRE.native_int8


@pytest.mark.parametrize(("cpu", "requested", "expected", "warns"), [
    (SAPPHIRE, "auto", "bf16", False),
    (EPYC_AVX2, "auto", "fp32", False),
    (SAPPHIRE, "bf16", "bf16", False),
    (EPYC_AVX2, "bf16", "bf16", True),  # honoured, but the user is told it is emulated
    (SAPPHIRE, "fp32", "fp32", False),
    (EPYC_AVX2, "fp32", "fp32", False),
])
def test_resolve_precision(cpu, requested, expected, warns):
    precision, warning = resolve_precision(requested, "cpu", cpu)
    assert precision == expected
    assert (warning is not None) == warns
    if warns:
        assert "emulated" in warning and cpu.model in warning and "auto" in warning


def test_resolve_precision_rejects_unknown():
    with pytest.raises(ValueError, match="auto"):
        resolve_precision("fp16", "cpu", SAPPHIRE)
    assert PRECISION_CHOICES == ("auto", "fp32", "bf16")


def test_this_machine_is_described():
    info = cpu_info()
    assert info.model and info.capability
    assert set(info.flags) <= set(info.as_dict()["flags"])
    auto, warning = resolve_precision("auto")
    assert warning is None and auto == ("bf16" if info.native_bf16 else "fp32")


def test_manifest_records_the_cpu():
    from grip_bench.results.manifest import platform_info

    cpu = platform_info()["cpu"]
    assert cpu["model"] == cpu_info().model and cpu["native_bf16"] == cpu_info().native_bf16
