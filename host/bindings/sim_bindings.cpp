#include <nanobind/nanobind.h>

#include "impactsim.h"

namespace nb = nanobind;

NB_MODULE(_sim, m) {
  m.doc() = "impactsense finite-element simulator";
  m.def("version", &impactsim::version);
}
