#include "impactsim.h"
namespace impactsim {
int version() { return 0; }
}
