# Checks that core/src's stage folders are layers: a file may include headers of its
# own stage or of a stage before it, never after. Run by ctest (core_layers, the unit
# tier) and by hand: cmake -P core/check_layers.cmake
#
# The stages, in order (core/CMakeLists.txt builds them in this order too):
set(stages base predicates search walks mesh cells io)
# A file's stage is its folder (core/src/STAGE/...). A public header
# (core/include/spokemesh/NAME.hpp) belongs to the stage whose folder holds NAME.cpp.
get_filename_component(core "${CMAKE_CURRENT_LIST_DIR}" ABSOLUTE)

function(stage_index stage out)
  list(FIND stages "${stage}" i)
  set(${out} ${i} PARENT_SCOPE)
endfunction()

# Public headers -> stage.
file(GLOB public RELATIVE "${core}/include/spokemesh" "${core}/include/spokemesh/*.hpp")
set(problems "")
foreach(header IN LISTS public)
  string(REGEX REPLACE "\\.hpp$" "" name "${header}")
  file(GLOB homes RELATIVE "${core}/src" "${core}/src/*/${name}.cpp")
  list(LENGTH homes count)
  if(NOT count EQUAL 1)
    string(APPEND problems "  spokemesh/${header}: no single core/src/<stage>/${name}.cpp to place it in a stage\n")
    continue()
  endif()
  string(REGEX REPLACE "/.*" "" stage "${homes}")
  set(public_stage_${name} "${stage}")
endforeach()

# Every file's includes, in src and include.
file(GLOB_RECURSE sources RELATIVE "${core}" "${core}/src/*.cpp" "${core}/src/*.hpp" "${core}/include/spokemesh/*.hpp")
foreach(source IN LISTS sources)
  if(source MATCHES "^src/([^/]+)/")
    set(from "${CMAKE_MATCH_1}")
  else()
    string(REGEX REPLACE "^include/spokemesh/(.*)\\.hpp$" "\\1" name "${source}")
    set(from "${public_stage_${name}}")
  endif()
  stage_index("${from}" from_index)
  if(from_index LESS 0)
    if(source MATCHES "^src/")
      string(APPEND problems "  ${source}: its folder is not a stage (${stages})\n")
    endif()
    continue()
  endif()
  file(STRINGS "${core}/${source}" includes REGEX "^[ \t]*#[ \t]*include[ \t]+\"")
  foreach(line IN LISTS includes)
    string(REGEX REPLACE "^[ \t]*#[ \t]*include[ \t]+\"([^\"]+)\".*" "\\1" target "${line}")
    if(target MATCHES "^spokemesh/(.*)\\.hpp$")
      set(to "${public_stage_${CMAKE_MATCH_1}}")
    elseif(target MATCHES "^([^/]+)/")
      set(to "${CMAKE_MATCH_1}")
    else()
      continue()
    endif()
    stage_index("${to}" to_index)
    if(to_index GREATER from_index)
      string(APPEND problems "  ${source} (${from}) includes ${target} (${to}), a later stage\n")
    endif()
  endforeach()
endforeach()

if(problems)
  message(FATAL_ERROR "core/src's stages (${stages}) must include only downwards:\n${problems}"
                      "Move the code to the stage of its users, or its users' needs to a lower stage.")
endif()
list(LENGTH sources checked)
message(STATUS "core layers: ${checked} files include only their own or earlier stages")
