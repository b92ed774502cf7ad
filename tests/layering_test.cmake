# Fails when a module includes what its layer must not see (docs/design.md, "Layers": dependencies flow
# one way"). Run by CTest as: cmake -DSOURCE_DIR=<repo> -P layering_test.cmake
set(failures "")

# check_folder(folder forbidden_regex why [allowed_regex]): an include matching forbidden_regex
# fails unless it also matches allowed_regex.
function(check_folder folder forbidden_regex why)
  set(allowed_regex "")
  if(ARGC GREATER 3)
    set(allowed_regex "${ARGV3}")
  endif()
  file(GLOB_RECURSE files ${SOURCE_DIR}/${folder}/*.h ${SOURCE_DIR}/${folder}/*.cc ${SOURCE_DIR}/${folder}/*.cpp)
  foreach(f ${files})
    file(STRINGS ${f} lines REGEX "^[ \t]*#[ \t]*include")
    foreach(line ${lines})
      if(allowed_regex AND line MATCHES "${allowed_regex}")
        continue()
      endif()
      if(line MATCHES "${forbidden_regex}")
        file(RELATIVE_PATH rel ${SOURCE_DIR} ${f})
        set(failures "${failures}\n  ${rel}: ${line}  (${why})")
      endif()
    endforeach()
  endforeach()
  set(failures "${failures}" PARENT_SCOPE)
endfunction()

set(backends "[<\"](mujoco/|mujoco\\.h|embree3/|OpenNI|openni2/|Driver/Oni|PS1080|romunect/sim/|romunect/sensor/embree/|romunect/sensor/openni2/)")
check_folder(fusion "${backends}" "fusion runs on real frames: sensor model only")
check_folder(calib "${backends}" "calib runs on real frames: sensor model only")
check_folder(fusion "[<\"]romunect/calib/" "fusion and calib are siblings")
# The hardware path sees no simulator: live frames reach it through feed_abi.h and dlopen.
check_folder(sensor/openni2 "[<\"](mujoco/|mujoco\\.h|embree3/|romunect/sim/|romunect/sim/openni2_feed/)" "sensor/openni2 loads the simulator's feed through feed_abi.h only")
check_folder(calib "[<\"]romunect/fusion/" "fusion and calib are siblings")
# sim implements calib's hardware port (CalibrationHardware, romunect/calib/chain.h) for the
# simulated rig: the port's header, which also declares the chain whose result the rig is
# compared against, is the only calib header sim sees.
check_folder(sim "[<\"]romunect/calib/" "sim sees calib through its port, romunect/calib/chain.h, only"
             "[<\"]romunect/calib/chain\\.h[>\"]")

# The sensor model (sensor/include, sensor/src) sees only Eigen, OpenCV and file formats.
file(GLOB sensor_files ${SOURCE_DIR}/sensor/include/romunect/sensor/*.h ${SOURCE_DIR}/sensor/src/*.h ${SOURCE_DIR}/sensor/src/*.cc)
foreach(f ${sensor_files})
  file(STRINGS ${f} lines REGEX "^[ \t]*#[ \t]*include")
  foreach(line ${lines})
    if(line MATCHES "${backends}|[<\"]romunect/(calib|fusion)/")
      file(RELATIVE_PATH rel ${SOURCE_DIR} ${f})
      set(failures "${failures}\n  ${rel}: ${line}  (the sensor model is layer 1)")
    endif()
  endforeach()
endforeach()

# Public headers of calib and fusion use Eigen, OpenCV core and our own types only.
foreach(folder calib fusion)
  file(GLOB_RECURSE headers ${SOURCE_DIR}/${folder}/include/*.h)
  foreach(f ${headers})
    file(STRINGS ${f} lines REGEX "^[ \t]*#[ \t]*include[ \t]*<")
    foreach(line ${lines})
      if(line MATCHES "<(ceres|glog|nlohmann|opencv2/(calib3d|imgproc|imgcodecs|features2d))")
        file(RELATIVE_PATH rel ${SOURCE_DIR} ${f})
        set(failures "${failures}\n  ${rel}: ${line}  (public headers: Eigen, OpenCV core, romunect)")
      endif()
    endforeach()
  endforeach()
endforeach()

if(failures)
  message(FATAL_ERROR "layering violations:${failures}")
endif()
message(STATUS "layering: ok")
