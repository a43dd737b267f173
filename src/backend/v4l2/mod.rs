//! The V4L2 camera and its lens (video node and lens sub-device).
