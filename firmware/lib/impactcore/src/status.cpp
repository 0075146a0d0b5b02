#include "impactcore.h"

namespace impactcore {

const uint8_t kPairI[kPairs] = {0, 0, 0, 1, 1, 2};
const uint8_t kPairJ[kPairs] = {1, 2, 3, 2, 3, 3};

const char* status_name(int32_t status) {
  switch (status) {
#define IMPACTCORE_STATUS_TEXT(code, name, key, text) \
  case name:                                          \
    return text;
    IMPACTCORE_STATUS(IMPACTCORE_STATUS_TEXT)
#undef IMPACTCORE_STATUS_TEXT
    default: return "unknown status";
  }
}

const char* status_key(int32_t status) {
  switch (status) {
#define IMPACTCORE_STATUS_KEY(code, name, key, text) \
  case name:                                         \
    return key;
    IMPACTCORE_STATUS(IMPACTCORE_STATUS_KEY)
#undef IMPACTCORE_STATUS_KEY
    default: return "unknown";
  }
}

}  // namespace impactcore
