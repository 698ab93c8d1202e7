// Internal: what every kernel module's driver (block_match.cpp, semi_global.cpp, depth.cpp,
// reproject.cpp, remap.cpp) needs: its kernel table for an instruction set, and the error for
// a parameter that breaks its rule.
#pragma once

#include <sstream>
#include <stdexcept>
#include <string>

#include "stereodepth/dispatch.hpp"

// The kernel table `getter()` of the build for `isa`: each module's kernels are compiled once
// per instruction set into stereodepth::detail::<isa> (see dispatch.hpp), and each build has a
// function returning its table. Without the x86 builds (STEREODEPTH_HAVE_X86_ISAS unset) only
// the baseline one exists.
#if defined(STEREODEPTH_HAVE_X86_ISAS)
#define STEREODEPTH_KERNELS_FOR(isa, getter)                                              \
  ((isa) == ::stereodepth::Isa::kAvx512 ? ::stereodepth::detail::avx512::getter()         \
   : (isa) == ::stereodepth::Isa::kAvx2 ? ::stereodepth::detail::avx2::getter()           \
                                        : ::stereodepth::detail::baseline::getter())
#else
#define STEREODEPTH_KERNELS_FOR(isa, getter) \
  ((void)(isa), ::stereodepth::detail::baseline::getter())
#endif

namespace stereodepth::detail {

// Throws std::invalid_argument("<rule>, got <value>"): the bindings turn it into a ValueError
// whose message names the parameter (the rule starts with its name) and what was received.
template <typename T>
[[noreturn]] void fail(const std::string& rule, T got) {
  std::ostringstream msg;
  msg << rule << ", got " << got;
  throw std::invalid_argument(msg.str());
}

}  // namespace stereodepth::detail
