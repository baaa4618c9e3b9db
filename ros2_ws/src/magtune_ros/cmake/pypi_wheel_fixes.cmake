# The PyPI ROS 2 wheels export CMake targets whose INTERFACE_INCLUDE_DIRECTORIES name the
# include directory of the interpreter they were built with (/opt/python/cp311-cp311/...),
# which does not exist here; CMake refuses such targets. Drop the directories that do not exist.
function(pypi_wheel_fix_include_dirs)
  foreach(pkg ${ARGN})
    find_package(${pkg} REQUIRED)
    set(t ${pkg}::${pkg}__rosidl_generator_py)
    if(TARGET ${t})
      get_target_property(dirs ${t} INTERFACE_INCLUDE_DIRECTORIES)
      set(keep "")
      foreach(d ${dirs})
        if(EXISTS "${d}" OR d MATCHES "^\\$<")
          list(APPEND keep "${d}")
        endif()
      endforeach()
      set_target_properties(${t} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${keep}")
    endif()
  endforeach()
endfunction()
