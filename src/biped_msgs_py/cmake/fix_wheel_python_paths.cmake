# The ROS 2 Jazzy wheels from PyPI were built in a manylinux container whose Python lived in
# /opt/python/cp311-cp311. Their exported CMake targets <pkg>::<pkg>__rosidl_generator_py carry
# that path in INTERFACE_INCLUDE_DIRECTORIES (Python.h and numpy headers). CMake refuses, at its
# generate step, an imported target that names a non-existent include directory, so a package
# whose messages depend on such a package (ours depend on builtin_interfaces, geometry_msgs, ...)
# fails to configure.
#
# This file rewrites, on the imported targets of the calling directory, exactly those paths:
#   /opt/python/<tag>/include/python3.X                  -> Python3_INCLUDE_DIRS (this interpreter)
#   /opt/python/<tag>/lib/python3.X/site-packages/<rest> -> <this interpreter's purelib>/<rest>
# and fails loudly on any other non-existent include path (nothing else is silently ignored).
# It does not touch the installed wheels or the file system outside the build.

function(biped_fix_wheel_python_paths)
  if(NOT Python3_EXECUTABLE)
    message(FATAL_ERROR "biped_fix_wheel_python_paths: Python3_EXECUTABLE is not set")
  endif()
  execute_process(
    COMMAND "${Python3_EXECUTABLE}" -c
      "import sysconfig; print(sysconfig.get_paths()['include']); print(sysconfig.get_paths()['purelib'])"
    OUTPUT_VARIABLE _out RESULT_VARIABLE _rc OUTPUT_STRIP_TRAILING_WHITESPACE)
  if(NOT _rc EQUAL 0)
    message(FATAL_ERROR "biped_fix_wheel_python_paths: cannot query ${Python3_EXECUTABLE}")
  endif()
  string(REPLACE "\n" ";" _out "${_out}")
  list(GET _out 0 _py_include)
  list(GET _out 1 _py_purelib)
  if(NOT EXISTS "${_py_include}/Python.h")
    message(FATAL_ERROR "biped_fix_wheel_python_paths: no Python.h in ${_py_include} (install the Python headers)")
  endif()

  get_property(_targets DIRECTORY PROPERTY IMPORTED_TARGETS)
  set(_n_fixed 0)
  foreach(_t IN LISTS _targets)
    get_target_property(_dirs ${_t} INTERFACE_INCLUDE_DIRECTORIES)
    if(NOT _dirs)
      continue()
    endif()
    set(_new "")
    set(_changed FALSE)
    foreach(_d IN LISTS _dirs)
      if(_d MATCHES "^\\$<" OR EXISTS "${_d}")
        list(APPEND _new "${_d}")
      elseif(_d MATCHES "^/opt/python/[^/]+/include/python3\\.[0-9]+$")
        list(APPEND _new "${_py_include}")
        set(_changed TRUE)
      elseif(_d MATCHES "^/opt/python/[^/]+/lib/python3\\.[0-9]+/site-packages/(.*)$")
        set(_mapped "${_py_purelib}/${CMAKE_MATCH_1}")
        if(NOT EXISTS "${_mapped}")
          message(FATAL_ERROR "biped_fix_wheel_python_paths: ${_t}: ${_d} maps to ${_mapped}, which does not exist")
        endif()
        list(APPEND _new "${_mapped}")
        set(_changed TRUE)
      else()
        message(FATAL_ERROR "biped_fix_wheel_python_paths: imported target ${_t} names the non-existent include directory ${_d}")
      endif()
    endforeach()
    if(_changed)
      list(REMOVE_DUPLICATES _new)
      set_target_properties(${_t} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_new}")
      math(EXPR _n_fixed "${_n_fixed} + 1")
    endif()
  endforeach()
  message(STATUS "biped_fix_wheel_python_paths: rewrote /opt/python/... include paths of ${_n_fixed} imported target(s) to ${_py_include}")
endfunction()
