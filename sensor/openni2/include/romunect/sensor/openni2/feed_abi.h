/* The C ABI of a frame feed: a shared library that the virtual device's driver plug-in
 * (virtual_device.h) loads with dlopen to present frames produced elsewhere (the simulator,
 * sim/openni2_feed) as an OpenNI2 device, without the driver or sensor/openni2 linking it.
 * Plain C, so a feed may be built by any compiler or project.
 *
 * A feed library exports three functions named as below. The driver calls them from one
 * thread at a time per feed. Frames: depth in metres along the optical axis (0 = none), IR as
 * 16-bit counts, both row-major width x height; time in seconds since the feed's first frame.
 * Version 2 adds a colour camera (its image 8-bit R, G, B, row-major color_width x color_height);
 * the driver zeroes both structs before a call, so a version 1 feed simply has no colour.
 */
#ifndef ROMUNECT_OPENNI2_FEED_ABI_H_
#define ROMUNECT_OPENNI2_FEED_ABI_H_

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define ROMUNECT_FEED_ABI_VERSION 2

typedef struct RomunectFeedInfo {
  int abi_version;       /* ROMUNECT_FEED_ABI_VERSION of the feed */
  int width, height;     /* image size (px) */
  double fx, fy, cx, cy; /* pinhole of the images (px): the device's fields of view */
  double fps;            /* frame rate (Hz) */
  int frame_count;       /* frames the feed will deliver; 0 = endless */
  int has_depth, has_ir; /* which images every frame holds */
  /* Version 2: a colour camera beside the depth camera (has_color = 1 when every frame holds its
   * image): its size and pinhole (px, no distortion) and its pose in the depth camera's frame
   * (row-major 4x4, rigid, colour camera to depth camera). */
  int has_color;
  int color_width, color_height;
  double color_fx, color_fy, color_cx, color_cy;
  double T_C_RGB[16];
} RomunectFeedInfo;

typedef struct RomunectFeedFrame {
  const float* depth_m; /* width * height, or NULL without depth */
  const uint16_t* ir;   /* width * height, or NULL without IR */
  double time_s;
  const uint8_t* color_rgb; /* version 2: color_width * color_height * 3, or NULL */
} RomunectFeedFrame;

/* Creates a feed from its query ("key=value&..."; the keys are the feed's own) and fills *info.
 * Returns NULL on failure with a message in error (error_size bytes, NUL-terminated). */
typedef void* (*RomunectFeedCreateFn)(const char* query, RomunectFeedInfo* info, char* error, int error_size);
/* Produces the next frame into *frame (its buffers stay valid until the next call or destroy).
 * Returns 1 for a frame, 0 at the end of the feed, -1 on failure (message in error). */
typedef int (*RomunectFeedNextFn)(void* feed, RomunectFeedFrame* frame, char* error, int error_size);
typedef void (*RomunectFeedDestroyFn)(void* feed);

#define ROMUNECT_FEED_CREATE_SYMBOL "romunect_feed_create"
#define ROMUNECT_FEED_NEXT_SYMBOL "romunect_feed_next"
#define ROMUNECT_FEED_DESTROY_SYMBOL "romunect_feed_destroy"

#ifdef __cplusplus
}
#endif

#endif /* ROMUNECT_OPENNI2_FEED_ABI_H_ */
