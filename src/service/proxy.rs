//! The client side of `org.focusd.Focusd1`, for `focusd trigger` and for tests that drive the
//! service: zbus generates `Focusd1Proxy` and its signal streams from this declaration, which
//! mirrors `daemon::Focusd`.

#[zbus::proxy(
    interface = "org.focusd.Focusd1",
    default_service = "org.focusd.Focusd",
    default_path = "/org/focusd/Focusd"
)]
pub trait Focusd1 {
    fn capture(&self) -> zbus::Result<String>;
    fn cancel(&self, job: &str) -> zbus::Result<()>;
    #[zbus(signal)]
    fn progress(&self, job: &str, stage: &str, done: u32, total: u32) -> zbus::Result<()>;
    #[zbus(signal)]
    fn finished(&self, job: &str, path: &str) -> zbus::Result<()>;
    #[zbus(signal)]
    fn failed(&self, job: &str, error: &str) -> zbus::Result<()>;
    #[zbus(property)]
    fn state(&self) -> zbus::Result<String>;
    #[zbus(property)]
    fn last_result(&self) -> zbus::Result<String>;
    #[zbus(property)]
    fn version(&self) -> zbus::Result<String>;
}
