# Checks the module layering of README.md ("Layout") on every project #include of every source
# file: a room may include only itself and the rooms below it. Run by ctest as `layering`:
#   cmake -DSOURCE_DIR=<repository root> -P check_layering.cmake
# Fails (FATAL_ERROR) listing each offending file:line and include; prints the include count.
cmake_minimum_required(VERSION 3.25)
if(NOT DEFINED SOURCE_DIR)
  message(FATAL_ERROR "check_layering.cmake: pass -DSOURCE_DIR=<repository root>")
endif()

# The project's rooms: an include whose first path segment is not one of these (a third-party
# header) is not checked.
set(rooms shaders engine calib render acquire bench cli tests)
# room (folder) -> rooms it may include. A sub-folder listed here overrides its room's rule.
set(allowed_engine engine shaders)
set(allowed_calib calib engine shaders)
set(allowed_render render engine shaders)
set(allowed_acquire acquire calib engine shaders)
# Synthetic captures render their photographs with the CPU reference renderer.
set(allowed_acquire/synth acquire calib render engine shaders)
set(allowed_bench/suite bench acquire calib render engine shaders)
set(allowed_cli cli bench acquire calib render engine shaders)
set(checked engine calib render acquire acquire/synth bench/suite cli)

set(violations "")
set(count 0)
foreach(folder IN LISTS checked)
  file(GLOB_RECURSE files LIST_DIRECTORIES false
       "${SOURCE_DIR}/${folder}/*.h" "${SOURCE_DIR}/${folder}/*.cc")
  foreach(file IN LISTS files)
    file(RELATIVE_PATH rel "${SOURCE_DIR}" "${file}")
    # The most specific rule that covers the file.
    set(rule "")
    foreach(candidate IN LISTS checked)
      string(LENGTH "${candidate}" n)
      string(SUBSTRING "${rel}" 0 ${n} head)
      if(head STREQUAL candidate)
        string(LENGTH "${rule}" m)
        if(n GREATER m)
          set(rule "${candidate}")
        endif()
      endif()
    endforeach()
    if(NOT rule STREQUAL folder)
      continue()  # checked under its more specific rule
    endif()
    file(STRINGS "${file}" lines REGEX "^[ \t]*#[ \t]*include[ \t]+\"")
    foreach(line IN LISTS lines)
      if(NOT line MATCHES "#[ \t]*include[ \t]+\"([A-Za-z0-9_]+)/")
        continue()
      endif()
      set(target "${CMAKE_MATCH_1}")
      if(NOT target IN_LIST rooms)
        continue()
      endif()
      math(EXPR count "${count} + 1")
      if(NOT target IN_LIST allowed_${rule})
        string(STRIP "${line}" line)
        list(APPEND violations "${rel}: ${line} (${rule} may include: ${allowed_${rule}})")
      endif()
    endforeach()
  endforeach()
endforeach()

if(count EQUAL 0)
  message(FATAL_ERROR "check_layering.cmake: no project includes found under ${SOURCE_DIR}")
endif()
if(violations)
  list(JOIN violations "\n  " text)
  message(FATAL_ERROR "layering violations (README.md, Layout):\n  ${text}")
endif()
message(STATUS "layering: ${count} project includes checked, all downward")
