//! The IIO gyroscope and accelerometer (Linux industrial I/O, through sysfs and /dev/iio:deviceN).
