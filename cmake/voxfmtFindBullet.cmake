# voxfmt_find_bullet(DOUBLE): defines the imported target voxfmt::bullet_libs (Bullet's dynamics, collision and
# linear-math libraries and include folder). Used by the build and by the installed package, so the package
# finds Bullet on the consuming machine instead of carrying this machine's paths.
function(voxfmt_find_bullet double)
  if(TARGET voxfmt::bullet_libs)
    return()
  endif()
  find_path(VOXFMT_BULLET_INCLUDE_DIR btBulletDynamicsCommon.h PATH_SUFFIXES bullet)
  set(suffix "")
  if(double)
    set(suffix "-float64")
  endif()
  set(libs "")
  foreach(lib BulletDynamics BulletCollision LinearMath)
    find_library(VOXFMT_BULLET_${lib} NAMES ${lib}${suffix})
    if(NOT VOXFMT_BULLET_${lib})
      message(FATAL_ERROR "voxfmt: Bullet library ${lib}${suffix} not found (Debian: libbullet-dev)")
    endif()
    list(APPEND libs ${VOXFMT_BULLET_${lib}})
  endforeach()
  if(NOT VOXFMT_BULLET_INCLUDE_DIR)
    message(FATAL_ERROR "voxfmt: Bullet headers not found (Debian: libbullet-dev)")
  endif()
  add_library(voxfmt::bullet_libs INTERFACE IMPORTED GLOBAL)
  set_target_properties(voxfmt::bullet_libs PROPERTIES
    INTERFACE_LINK_LIBRARIES "${libs}"
    INTERFACE_SYSTEM_INCLUDE_DIRECTORIES "${VOXFMT_BULLET_INCLUDE_DIR}"
    INTERFACE_INCLUDE_DIRECTORIES "${VOXFMT_BULLET_INCLUDE_DIR}")
  if(double)
    set_property(TARGET voxfmt::bullet_libs PROPERTY INTERFACE_COMPILE_DEFINITIONS BT_USE_DOUBLE_PRECISION)
  endif()
endfunction()
