nanobind_add_module(_core NB_STATIC ${CMAKE_CURRENT_LIST_DIR}/core_bindings.cpp)
target_link_libraries(_core PRIVATE impactcore)
install(TARGETS _core LIBRARY DESTINATION impactsense)
