//! Implementations of the capture traits: the phone's hardware (V4L2 camera and lens, IIO
//! gyroscope and accelerometer, evdev trigger keys) and the replay of recorded bundles.
pub mod iio;
pub mod input;
pub mod replay;
pub mod sys;
pub mod v4l2;
pub mod videodev;
