# Given as CMAKE_PROJECT_INCLUDE when an interface package is built against ROS 2's PyPI
# wheels (scripts/build_interfaces.sh, scripts/colcon_check.sh); not needed with a ROS
# install. The wheels' exported *__rosidl_generator_py targets name an include directory of
# the machine that built them, and cmake refuses a target whose include directory does not
# exist. Once the package's CMakeLists.txt has been read, this drops such directories from
# the imported targets (the package itself stays as it is in a ROS workspace).
function(sfs_drop_missing_includes)
  get_property(targets DIRECTORY "${CMAKE_SOURCE_DIR}" PROPERTY IMPORTED_TARGETS)
  foreach(target IN LISTS targets)
    get_target_property(dirs ${target} INTERFACE_INCLUDE_DIRECTORIES)
    if(dirs)
      set(kept)
      foreach(dir IN LISTS dirs)
        if(EXISTS "${dir}" OR dir MATCHES "^[$]<")
          list(APPEND kept "${dir}")
        endif()
      endforeach()
      set_target_properties(${target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${kept}")
    endif()
  endforeach()
endfunction()
cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL sfs_drop_missing_includes)
