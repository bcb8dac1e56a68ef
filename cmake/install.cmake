# `cmake --install build --prefix P` installs the libraries geomfit::core, geomfit::proto
# and geomfit::client (static, with their headers under P/include), the programs geomfit
# and geomfit-server (imported as geomfit::cli and geomfit::server), and
# P/lib/cmake/geomfit/geomfitConfig.cmake, so that a downstream project can
#   find_package(geomfit 0.1 REQUIRED)
#   target_link_libraries(app PRIVATE geomfit::core)      # or geomfit::client
include(GNUInstallDirs)
include(CMakePackageConfigHelpers)

set(GEOMFIT_CMAKE_DIR ${CMAKE_INSTALL_LIBDIR}/cmake/geomfit)
set_target_properties(geomfit_core PROPERTIES EXPORT_NAME core)
set(geomfit_install_targets geomfit_core)
install(DIRECTORY ${PROJECT_SOURCE_DIR}/core/ DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}/core
        FILES_MATCHING PATTERN "*.h")
if(TARGET geomfit_proto)
  set_target_properties(geomfit_proto PROPERTIES EXPORT_NAME proto)
  list(APPEND geomfit_install_targets geomfit_proto)
  install(FILES ${PROJECT_SOURCE_DIR}/proto/wire.h DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}/proto)
  install(DIRECTORY ${PROJECT_BINARY_DIR}/proto/gen/geomfit DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}
          FILES_MATCHING PATTERN "*.h")
  install(DIRECTORY ${PROJECT_SOURCE_DIR}/proto/geomfit DESTINATION ${CMAKE_INSTALL_DATADIR}/geomfit/proto
          FILES_MATCHING PATTERN "*.proto")
endif()
if(TARGET geomfit_client)
  set_target_properties(geomfit_client PROPERTIES EXPORT_NAME client)
  list(APPEND geomfit_install_targets geomfit_client)
  install(FILES ${PROJECT_SOURCE_DIR}/clients/cpp/client/client.h
          DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}/clients/cpp/client)
endif()
if(TARGET geomfit)
  set_target_properties(geomfit PROPERTIES EXPORT_NAME cli)
  list(APPEND geomfit_install_targets geomfit)
endif()
if(TARGET geomfit-full)  # the commands the lean `geomfit` front end hands on (exec, same folder)
  set_target_properties(geomfit-full PROPERTIES EXPORT_NAME cli_full)
  list(APPEND geomfit_install_targets geomfit-full)
endif()
if(TARGET geomfit-server)
  set_target_properties(geomfit-server PROPERTIES EXPORT_NAME server)
  list(APPEND geomfit_install_targets geomfit-server)
endif()

install(TARGETS ${geomfit_install_targets} EXPORT geomfitTargets
        ARCHIVE DESTINATION ${CMAKE_INSTALL_LIBDIR}
        LIBRARY DESTINATION ${CMAKE_INSTALL_LIBDIR}
        RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
install(EXPORT geomfitTargets NAMESPACE geomfit:: DESTINATION ${GEOMFIT_CMAKE_DIR})

configure_package_config_file(${CMAKE_CURRENT_LIST_DIR}/geomfitConfig.cmake.in
                              ${PROJECT_BINARY_DIR}/geomfitConfig.cmake INSTALL_DESTINATION ${GEOMFIT_CMAKE_DIR})
write_basic_package_version_file(${PROJECT_BINARY_DIR}/geomfitConfigVersion.cmake
                                 COMPATIBILITY SameMinorVersion)
install(FILES ${PROJECT_BINARY_DIR}/geomfitConfig.cmake ${PROJECT_BINARY_DIR}/geomfitConfigVersion.cmake
        DESTINATION ${GEOMFIT_CMAKE_DIR})
