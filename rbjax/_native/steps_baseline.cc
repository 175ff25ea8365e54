// The per-block steps (steps.h) for the x86-64 baseline (or any other processor): see block.h.
#include "block.h"
namespace rbjax_native {
namespace baseline {
#include "steps.h"
}  // namespace baseline
}  // namespace rbjax_native
