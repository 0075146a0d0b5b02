# impactsense._link: the wire protocol codec (firmware/lib/impactlink) and the portable firmware app
# (firmware/lib/impactapp), compiled natively for the emulator, the monitor and the tests.
if(NOT TARGET impactlink)
  add_subdirectory(${CMAKE_CURRENT_LIST_DIR}/../../firmware/lib/impactlink ${CMAKE_BINARY_DIR}/impactlink)
endif()
if(NOT TARGET impactapp)
  add_subdirectory(${CMAKE_CURRENT_LIST_DIR}/../../firmware/lib/impactapp ${CMAKE_BINARY_DIR}/impactapp)
endif()
nanobind_add_module(_link NB_STATIC ${CMAKE_CURRENT_LIST_DIR}/link_bindings.cpp)
target_link_libraries(_link PRIVATE impactapp impactlink impactcore)
install(TARGETS _link LIBRARY DESTINATION impactsense)
