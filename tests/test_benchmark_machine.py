"""What a benchmark result records of the machine it was measured on."""

ZEN4 = """processor\t: 0
vendor_id\t: AuthenticAMD
model name\t: AMD EPYC
flags\t\t: fpu sse4_2 avx avx2 fma avx512f avx512dq avx512_bf16 avx512_vnni
"""
ZEN3 = """processor\t: 0
model name\t: AMD EPYC
flags\t\t: fpu sse4_2 avx avx2 fma
"""


def test_two_cpus_of_one_model_name_are_told_apart_by_their_vector_sets(benchmark_module):
    common = benchmark_module("_common")
    assert common.cpu_simd(ZEN4) == ["avx2", "avx512f", "avx512_bf16"]
    assert common.cpu_simd(ZEN3) == ["avx2"]
    assert common.cpu_simd("model name\t: something without flags\n") == []
    assert set(common.machine()["simd"]) <= set(common.SIMD_FLAGS)


def test_benchmark_pools_spawn_their_workers(benchmark_module):
    """A forked worker of a process that has run Ray (an earlier test on the same pytest
    worker) crashed in Ray's library; every benchmark's pool spawns its workers instead."""
    common = benchmark_module("_common")
    with common.pool(0) as pool:  # at least one worker
        assert pool._mp_context.get_start_method() == "spawn"
        assert pool._max_workers == 1
