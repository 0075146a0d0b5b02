#include "impactcore.h"

namespace impactcore {

const uint8_t kPairI[kPairs] = {0, 0, 0, 1, 1, 2};
const uint8_t kPairJ[kPairs] = {1, 2, 3, 2, 3, 3};

const char* status_name(int32_t status) {
  switch (status) {
    case kOk: return "ok";
    case kErrNullInput: return "null input";
    case kErrTooManySamples: return "capture longer than kMaxSamples";
    case kErrTooFewSamples: return "capture shorter than the baseline segment";
    case kErrBadConfig: return "invalid configuration";
    case kErrNoTrigger: return "no channel crossed the onset threshold";
    case kErrSingular: return "degenerate geometry";
    default: return "unknown status";
  }
}

}  // namespace impactcore
