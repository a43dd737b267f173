//! `focusd-viewfinder`: the camera app for focusd on a phone. It shows the daemon's live
//! preview, takes a focus stack with one button, shows the stages while the daemon works, and
//! the result as a thumbnail that opens the picture.

mod link;
mod preview;
mod window;

use adw::prelude::*;
use gettextrs::{bindtextdomain, setlocale, textdomain, LocaleCategory};

/// The app id: not the daemon's bus name, which the service and its activation own.
const APP_ID: &str = "org.focusd.Viewfinder";
/// The gettext domain of the app's strings.
const DOMAIN: &str = "focusd-viewfinder";

fn main() -> gtk::glib::ExitCode {
    setlocale(LocaleCategory::LcAll, "");
    // Without translations installed the strings stay English.
    let _ = bindtextdomain(DOMAIN, "/usr/share/locale");
    let _ = textdomain(DOMAIN);
    let app = adw::Application::builder().application_id(APP_ID).build();
    app.connect_activate(window::present);
    app.run()
}
