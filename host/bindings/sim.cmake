nanobind_add_module(_sim NB_STATIC ${CMAKE_CURRENT_LIST_DIR}/sim_bindings.cpp)
target_link_libraries(_sim PRIVATE impactsim)
install(TARGETS _sim LIBRARY DESTINATION impactsense)
