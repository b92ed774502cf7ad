// The driver plug-in (libRomunectVirtual.so.0, virtual_driver.cc) and the backend it loads when a
// device opens (libRomunectVirtualBackend.so, virtual_device_backend.cc): both are built by this
// project with the same compiler, so C++ objects (a DeviceBase) cross between them.
#pragma once

#define XN_NEW(type, ...) new type(__VA_ARGS__)
#define XN_DELETE(p) delete (p)
#include <Driver/OniDriverAPI.h>

namespace romunect::openni2 {

// The backend's file: in <lib>, two folders above the driver folder <lib>/OpenNI2/Drivers.
inline constexpr const char* kVirtualBackendFile = "libRomunectVirtualBackend.so";

// Called once when a device's finite source has sent its last frame, with the URI it was opened
// by, from the device's producer thread (or the application's, in step pace), maybe with the
// device's lock held: the driver queues it and raises OpenNI2's end-of-file state and
// device-disconnected events on a thread of its own.
using VirtualBackendEndedFn = void (*)(const char* uri);

// oni::driver::DeviceBase* romunect_virtual_backend_open(uri, services, ended, error, error_size):
// the device for a virtual-device URI, or nullptr with why in error.
inline constexpr const char* kVirtualBackendOpenSymbol = "romunect_virtual_backend_open";
using VirtualBackendOpenFn = oni::driver::DeviceBase* (*)(const char*, oni::driver::DriverServices*,
                                                          VirtualBackendEndedFn, char*, int);

// void romunect_virtual_backend_set_wait_hook(void (*hook)()): the producer's test hook.
inline constexpr const char* kVirtualBackendWaitHookSymbol = "romunect_virtual_backend_set_wait_hook";
using VirtualBackendWaitHookFn = void (*)(void (*)());

}  // namespace romunect::openni2
