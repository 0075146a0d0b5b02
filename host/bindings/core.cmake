nanobind_add_module(_core NB_STATIC ${CMAKE_CURRENT_LIST_DIR}/core_bindings.cpp)
target_link_libraries(_core PRIVATE impactcore)
install(TARGETS _core LIBRARY DESTINATION impactsense)
# The features' per-event work counters (impactcore.h WorkCounts): the host's build only, so the board's code is unchanged.
target_compile_definitions(impactcore PUBLIC IMPACTCORE_WORK_COUNTS)
