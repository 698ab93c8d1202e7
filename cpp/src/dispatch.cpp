#include "stereodepth/dispatch.hpp"

#include <cstdlib>
#include <stdexcept>

namespace stereodepth {
namespace {

bool cpu_supports(Isa isa) {
#if defined(__x86_64__) || defined(__i386__)
  switch (isa) {
    case Isa::kBaseline:
      return true;
    case Isa::kAvx2:
      return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma") &&
             __builtin_cpu_supports("bmi2") && __builtin_cpu_supports("popcnt");
    case Isa::kAvx512:
      return cpu_supports(Isa::kAvx2) && __builtin_cpu_supports("avx512f") &&
             __builtin_cpu_supports("avx512bw") && __builtin_cpu_supports("avx512vl") &&
             __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512vpopcntdq") &&
             __builtin_cpu_supports("avx512bitalg");
  }
  return false;
#else
  return isa == Isa::kBaseline;
#endif
}

Isa parse_isa(const std::string& name) {
  if (name == "baseline") return Isa::kBaseline;
  if (name == "avx2") return Isa::kAvx2;
  if (name == "avx512") return Isa::kAvx512;
  throw std::invalid_argument("isa must be one of 'auto', 'baseline', 'avx2', 'avx512', got '" +
                              name + "'");
}

Isa detect_default() {
  Isa best = Isa::kBaseline;
  for (Isa isa : supported_isas()) best = isa;
  if (const char* env = std::getenv("STEREODEPTH_ISA")) {
    const std::string name(env);
    if (!name.empty() && name != "auto") {
      Isa cap = Isa::kBaseline;
      if (name == "baseline") {
        cap = Isa::kBaseline;
      } else if (name == "avx2") {
        cap = Isa::kAvx2;
      } else if (name == "avx512") {
        cap = Isa::kAvx512;
      } else {
        // A mistyped cap must not silently run another ISA (a benchmark would name the wrong
        // one): every kernel call raises until it is fixed.
        throw std::invalid_argument(
            "the environment variable STEREODEPTH_ISA must be 'auto', 'baseline', 'avx2' or "
            "'avx512', got '" + name + "'");
      }
      if (static_cast<int>(cap) < static_cast<int>(best)) best = cap;
    }
  }
  return best;
}

}  // namespace

const char* isa_name(Isa isa) {
  switch (isa) {
    case Isa::kBaseline:
      return "baseline";
    case Isa::kAvx2:
      return "avx2";
    case Isa::kAvx512:
      return "avx512";
  }
  return "baseline";
}

std::vector<Isa> supported_isas() {
  std::vector<Isa> out;
  for (Isa isa : {Isa::kBaseline, Isa::kAvx2, Isa::kAvx512}) {
    if (cpu_supports(isa)) out.push_back(isa);
  }
  return out;
}

Isa default_isa() {
  static const Isa isa = detect_default();
  return isa;
}

Isa resolve_isa(const std::string& name) {
  if (name.empty() || name == "auto") return default_isa();
  const Isa isa = parse_isa(name);
  if (!cpu_supports(isa)) {
    throw std::invalid_argument("isa '" + name + "' is not supported by this CPU");
  }
  return isa;
}

}  // namespace stereodepth
