# Generates the bindings of lcmtypes/*.lcm:
#   C++    -> ${CMAKE_BINARY_DIR}/lcmtypes/cpp/marionette/*.hpp   (target marionette_lcmtypes)
#   Python -> ${MARIONETTE_PYTHON_OUT}/lcmt_*.py                  (imported as marionette.lcmt_*)
#   Java   -> ${CMAKE_BINARY_DIR}/lcmtypes/marionette_lcmtypes.jar (lcm-spy's classpath)
#   Bounds -> ${CMAKE_BINARY_DIR}/lcmtypes/cpp/marionette/lcm_bounds.hpp and
#             ${MARIONETTE_PYTHON_OUT}/lcm_bounds.py: the tables of the validators
#             (marionette::wire::Validate, marionette.lcm_validate), from the bounds annotated on
#             the fields (lcmtypes/README.md), by scripts/generate_lcm_bounds.py
# C++ and Java come from Debian's lcm-gen (matching liblcm 1.3); Python from the venv's
# lcm-gen (matching the lcm 1.5 wheel). Both compute the same fingerprints.
find_program(LCM_GEN lcm-gen PATHS /usr/bin NO_DEFAULT_PATH REQUIRED)
get_filename_component(_venv_bin ${Python_EXECUTABLE} DIRECTORY)
find_program(LCM_GEN_PY lcm-gen PATHS ${_venv_bin} NO_DEFAULT_PATH REQUIRED)
find_file(LCM_JAR lcm.jar PATHS /usr/share/java NO_DEFAULT_PATH REQUIRED)

file(GLOB LCM_TYPE_FILES CONFIGURE_DEPENDS ${PROJECT_SOURCE_DIR}/lcmtypes/*.lcm)
set(_cpp_dir ${CMAKE_BINARY_DIR}/lcmtypes/cpp)
set(_java_dir ${CMAKE_BINARY_DIR}/lcmtypes/java)
set(LCM_TYPES_JAR ${CMAKE_BINARY_DIR}/lcmtypes/marionette_lcmtypes.jar)
set(_cpp_headers "")
set(_py_files "")
set(_java_files "")
foreach(_lcm ${LCM_TYPE_FILES})
  get_filename_component(_name ${_lcm} NAME_WE)
  list(APPEND _cpp_headers ${_cpp_dir}/marionette/${_name}.hpp)
  list(APPEND _py_files ${MARIONETTE_PYTHON_OUT}/${_name}.py)
  list(APPEND _java_files ${_java_dir}/marionette/${_name}.java)
endforeach()

add_custom_command(
  OUTPUT ${_cpp_headers}
  COMMAND ${LCM_GEN} --cpp --cpp-hpath ${_cpp_dir} ${LCM_TYPE_FILES}
  DEPENDS ${LCM_TYPE_FILES}
  COMMENT "lcm-gen: C++ types")
# lcm-gen --python writes <ppath>/marionette/; the package's own __init__.py lives in python/.
add_custom_command(
  OUTPUT ${_py_files}
  COMMAND ${LCM_GEN_PY} --python --ppath ${CMAKE_BINARY_DIR}/python ${LCM_TYPE_FILES}
  COMMAND ${CMAKE_COMMAND} -E remove -f ${MARIONETTE_PYTHON_OUT}/__init__.py
  DEPENDS ${LCM_TYPE_FILES}
  COMMENT "lcm-gen: Python types")
add_custom_command(
  OUTPUT ${LCM_TYPES_JAR}
  COMMAND ${CMAKE_COMMAND} -E rm -rf ${_java_dir}
  COMMAND ${LCM_GEN} --java --jpath ${_java_dir} ${LCM_TYPE_FILES}
  COMMAND ${Java_JAVAC_EXECUTABLE} -nowarn -cp ${LCM_JAR} -d ${_java_dir}/classes ${_java_files}
  COMMAND ${Java_JAR_EXECUTABLE} cf ${LCM_TYPES_JAR} -C ${_java_dir}/classes .
  DEPENDS ${LCM_TYPE_FILES}
  COMMENT "lcm-gen: Java types -> marionette_lcmtypes.jar")
set(LCM_BOUNDS_HEADER ${_cpp_dir}/marionette/lcm_bounds.hpp)
set(_bounds_py ${MARIONETTE_PYTHON_OUT}/lcm_bounds.py)
set(_bounds_generator ${PROJECT_SOURCE_DIR}/scripts/generate_lcm_bounds.py)
add_custom_command(
  OUTPUT ${LCM_BOUNDS_HEADER} ${_bounds_py}
  COMMAND ${Python_EXECUTABLE} ${_bounds_generator} ${PROJECT_SOURCE_DIR}/lcmtypes
          ${LCM_BOUNDS_HEADER} ${_bounds_py}
  DEPENDS ${LCM_TYPE_FILES} ${_bounds_generator} ${PROJECT_SOURCE_DIR}/python/marionette/lcm_schema.py
  COMMENT "lcm bounds: validator tables from the annotated lcmtypes")
add_custom_target(marionette_lcmtypes_gen ALL
  DEPENDS ${_cpp_headers} ${_py_files} ${LCM_TYPES_JAR} ${LCM_BOUNDS_HEADER} ${_bounds_py})

add_library(marionette_lcmtypes INTERFACE)
add_dependencies(marionette_lcmtypes marionette_lcmtypes_gen)
# SYSTEM: lcm-gen's generated code is not ours to warn about.
target_include_directories(marionette_lcmtypes SYSTEM INTERFACE ${_cpp_dir})
target_link_libraries(marionette_lcmtypes INTERFACE PkgConfig::LCM)
