// Run-time choice of instruction set.
//
// Hot kernels are compiled once per instruction set (see STEREODEPTH_ISA_SOURCES in
// CMakeLists.txt): the baseline x86-64 build, AVX2 (+FMA, BMI2) and AVX-512 (F, BW, VL, DQ).
// Each build lives in its own namespace stereodepth::detail::<isa>. Because the same source is
// compiled with different -m flags, such a file must keep everything it defines inside that
// namespace and must not instantiate templates shared with other files (std containers,
// Eigen expressions) in its hot code: the linker would keep one copy of them, perhaps the
// AVX-512 one. Scratch memory is allocated by the caller in the baseline code and passed in.
#pragma once

#include <string>
#include <vector>

namespace stereodepth {

enum class Isa { kBaseline = 0, kAvx2 = 1, kAvx512 = 2 };

// "baseline", "avx2" or "avx512".
const char* isa_name(Isa isa);

// The best instruction set this CPU supports, capped by the environment variable
// STEREODEPTH_ISA (baseline|avx2|avx512) when it is set. Read once, then cached.
Isa default_isa();

// Every instruction set this CPU can run, baseline first.
std::vector<Isa> supported_isas();

// Resolves a name ("auto" or "" for default_isa()); throws std::invalid_argument for an
// unknown name or one this CPU cannot run.
Isa resolve_isa(const std::string& name);

}  // namespace stereodepth
