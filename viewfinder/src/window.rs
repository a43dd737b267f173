//! The one window: the preview filling it, a status line with the stage and its progress on
//! top, and beside the picture (below it in portrait, right of it in landscape) the result's
//! thumbnail, the shutter and, during a job, Cancel.

use crate::link::{Event, Link};
use crate::preview::{Look, Preview};
use adw::prelude::*;
use focusd::service::preview::ring::{RingReader, State};
use gettextrs::gettext;
use gtk::{gdk, gio, glib};
use std::cell::RefCell;
use std::rc::Rc;
use std::time::{Duration, Instant};

/// Phone-sized, portrait.
const WIDTH: i32 = 360;
const HEIGHT: i32 = 720;
/// The controls' margins: along them clear of the phone's rounded corners, and towards the
/// edge clear of its gesture area.
const SIDE_MARGIN: i32 = 24;
const BOTTOM_MARGIN: i32 = 32;
/// Between the picture and the controls.
const GAP: i32 = 12;
/// The result's thumbnail, a side.
const THUMBNAIL: i32 = 64;
/// How often the ring is looked at: twice the preview's rate, so no frame waits long.
const LOOK_EVERY: Duration = Duration::from_millis(33);
/// The daemon stops a preview nobody renews (`[service] preview_timeout_s`, at least 1 s
/// and 120 s by default); the app renews it well within the default.
const RENEW_EVERY: Duration = Duration::from_secs(45);
/// A preview that could not start is tried again this often.
const RETRY_EVERY: Duration = Duration::from_secs(3);

const CSS: &str = include_str!("style.css");

struct Ui {
    /// The picture's area and the controls, one after the other.
    layout: gtk::Box,
    controls: gtk::Box,
    picture: gtk::Picture,
    status: gtk::Label,
    progress: gtk::ProgressBar,
    message: gtk::Label,
    shutter: gtk::Button,
    cancel: gtk::Button,
    thumbnail: gtk::Button,
    thumbnail_picture: gtk::Image,
}

#[derive(Default)]
struct Session {
    preview: Option<Preview>,
    /// When the preview was last started or renewed, or last failed to start.
    asked: Option<Instant>,
    asking: bool,
    job: Option<String>,
    result: Option<String>,
}

struct App {
    ui: Ui,
    link: Link,
    session: RefCell<Session>,
}

/// Builds and shows the window of `app`.
pub fn present(app: &adw::Application) {
    // A viewfinder is dark, as every camera app is: the picture is what is bright.
    adw::StyleManager::default().set_color_scheme(adw::ColorScheme::ForceDark);
    let provider = gtk::CssProvider::new();
    provider.load_from_data(CSS);
    if let Some(display) = gdk::Display::default() {
        gtk::style_context_add_provider_for_display(
            &display,
            &provider,
            gtk::STYLE_PROVIDER_PRIORITY_APPLICATION,
        );
    }
    let ui = build(app);
    let (link, events) = match Link::new() {
        Ok(l) => l,
        Err(e) => {
            show_message(&ui, &format!("{}: {e}", gettext("Cannot start")));
            return;
        }
    };
    let me = Rc::new(App {
        ui,
        link,
        session: RefCell::default(),
    });
    connect(&me);
    glib::spawn_future_local(listen(me.clone(), events));
    let tick = me.clone();
    glib::timeout_add_local(LOOK_EVERY, move || {
        tick.tick();
        glib::ControlFlow::Continue
    });
}

fn build(app: &adw::Application) -> Ui {
    let picture = gtk::Picture::builder()
        .content_fit(gtk::ContentFit::Contain)
        .can_shrink(true)
        .hexpand(true)
        .vexpand(true)
        .build();
    picture.update_property(&[gtk::accessible::Property::Label(&gettext("Viewfinder"))]);
    let status = gtk::Label::builder()
        .css_classes(["status"])
        .wrap(true)
        .justify(gtk::Justification::Center)
        .visible(false)
        .build();
    let progress = gtk::ProgressBar::builder().visible(false).build();
    let top = gtk::Box::builder()
        .orientation(gtk::Orientation::Vertical)
        .spacing(8)
        .valign(gtk::Align::Start)
        .halign(gtk::Align::Fill)
        .margin_top(16)
        .margin_start(16)
        .margin_end(16)
        .build();
    let status_row = gtk::Box::builder().halign(gtk::Align::Center).build();
    status_row.append(&status);
    top.append(&status_row);
    top.append(&progress);
    let message = gtk::Label::builder()
        .css_classes(["message"])
        .wrap(true)
        .justify(gtk::Justification::Center)
        .valign(gtk::Align::Center)
        .halign(gtk::Align::Center)
        .margin_start(24)
        .margin_end(24)
        .visible(false)
        .build();
    let shutter = gtk::Button::builder()
        .css_classes(["shutter"])
        .tooltip_text(gettext("Take a focus stack"))
        .build();
    shutter.update_property(&[gtk::accessible::Property::Label(&gettext(
        "Take a focus stack",
    ))]);
    // An image, not a picture: it draws the paintable at its icon size, whatever the size of
    // the photo.
    let thumbnail_picture = gtk::Image::builder().pixel_size(THUMBNAIL).build();
    let thumbnail = gtk::Button::builder()
        .css_classes(["thumbnail"])
        .child(&thumbnail_picture)
        .tooltip_text(gettext("Open the last picture"))
        .visible(false)
        .build();
    let cancel = gtk::Button::builder()
        .label(gettext("Cancel"))
        .css_classes(["cancel"])
        .visible(false)
        .build();
    // Three equal thirds, so the shutter stays centred whatever is shown beside it; its own
    // expansion set, so the picture gets all the room the controls do not need.
    let controls = gtk::Box::builder()
        .homogeneous(true)
        .hexpand(false)
        .vexpand(false)
        .build();
    // Each in a slot that stays when its button hides: a homogeneous box shares out its room
    // among the children shown.
    for w in [
        thumbnail.upcast_ref::<gtk::Widget>(),
        shutter.upcast_ref(),
        cancel.upcast_ref(),
    ] {
        let slot = gtk::Box::builder().build();
        w.set_halign(gtk::Align::Center);
        w.set_valign(gtk::Align::Center);
        w.set_hexpand(true);
        w.set_vexpand(true);
        slot.append(w);
        controls.append(&slot);
    }
    let overlay = gtk::Overlay::builder()
        .child(&picture)
        .hexpand(true)
        .vexpand(true)
        .build();
    overlay.add_overlay(&top);
    overlay.add_overlay(&message);
    let layout = gtk::Box::builder().css_classes(["viewfinder"]).build();
    layout.append(&overlay);
    layout.append(&controls);
    arrange(&layout, &controls, false);
    let window = adw::ApplicationWindow::builder()
        .application(app)
        .title(gettext("Viewfinder"))
        .default_width(WIDTH)
        .default_height(HEIGHT)
        .content(&layout)
        .build();
    window.present();
    Ui {
        layout,
        controls,
        picture,
        status,
        progress,
        message,
        shutter,
        cancel,
        thumbnail,
        thumbnail_picture,
    }
}

/// Controls below the picture in portrait, in a column right of it in landscape: never over
/// the picture.
fn arrange(layout: &gtk::Box, controls: &gtk::Box, landscape: bool) {
    let (along, across) = if landscape {
        (gtk::Orientation::Horizontal, gtk::Orientation::Vertical)
    } else {
        (gtk::Orientation::Vertical, gtk::Orientation::Horizontal)
    };
    layout.set_orientation(along);
    controls.set_orientation(across);
    controls.set_margin_top(if landscape { SIDE_MARGIN } else { GAP });
    controls.set_margin_bottom(if landscape {
        SIDE_MARGIN
    } else {
        BOTTOM_MARGIN
    });
    controls.set_margin_start(if landscape { GAP } else { SIDE_MARGIN });
    controls.set_margin_end(if landscape {
        BOTTOM_MARGIN
    } else {
        SIDE_MARGIN
    });
}

fn show_message(ui: &Ui, text: &str) {
    ui.message.set_label(text);
    ui.message.set_visible(!text.is_empty());
}

fn connect(me: &Rc<App>) {
    let m = me.clone();
    me.ui.shutter.connect_clicked(move |_| {
        let m = m.clone();
        glib::spawn_future_local(async move {
            m.ui.shutter.set_sensitive(false);
            match m.link.capture().await {
                Ok(job) => m.started(job),
                Err(e) => {
                    m.ui.shutter.set_sensitive(true);
                    show_message(&m.ui, &e);
                }
            }
        });
    });
    let m = me.clone();
    me.ui.cancel.connect_clicked(move |_| {
        let Some(job) = m.session.borrow().job.clone() else {
            return;
        };
        let m = m.clone();
        glib::spawn_future_local(async move {
            if let Err(e) = m.link.cancel(job).await {
                show_message(&m.ui, &e);
            }
        });
    });
    let m = me.clone();
    me.ui.thumbnail.connect_clicked(move |_| {
        let Some(path) = m.session.borrow().result.clone() else {
            return;
        };
        let uri = gio::File::for_path(&path).uri();
        if let Err(e) = gio::AppInfo::launch_default_for_uri(&uri, None::<&gio::AppLaunchContext>) {
            show_message(
                &m.ui,
                &format!("{} {path}: {e}", gettext("No viewer opens")),
            );
        }
    });
}

/// Reads the daemon's events as they come.
async fn listen(me: Rc<App>, mut events: tokio::sync::mpsc::UnboundedReceiver<Event>) {
    while let Some(e) = events.recv().await {
        me.on_event(e);
    }
}

/// What a stage is called on screen.
fn stage_text(stage: &str, done: u32, total: u32) -> String {
    match stage {
        "waiting-still" => gettext("Hold still…"),
        "sweeping" => format!(
            "{} {}/{}",
            gettext("Hold still — sweeping the focus"),
            done,
            total
        ),
        "developing" => format!(
            "{} {}/{}",
            gettext("Developing the raw frames"),
            done,
            total
        ),
        "register" | "warp" => gettext("Developing: aligning the frames"),
        _ => gettext("Developing: fusing the sharpest parts"),
    }
}

impl App {
    fn started(&self, job: String) {
        self.session.borrow_mut().job = Some(job);
        show_message(&self.ui, "");
        self.ui.shutter.set_sensitive(false);
        self.ui.cancel.set_visible(true);
        self.ui.status.set_label(&gettext("Hold still…"));
        self.ui.status.set_visible(true);
    }

    fn ended(&self) {
        self.session.borrow_mut().job = None;
        self.ui.shutter.set_sensitive(true);
        self.ui.cancel.set_visible(false);
        self.ui.progress.set_visible(false);
        self.ui.status.set_visible(false);
    }

    fn on_event(&self, e: Event) {
        match e {
            Event::Progress {
                job,
                stage,
                done,
                total,
            } => {
                // A job a hardware key started shows the same.
                if self.session.borrow().job.as_deref() != Some(job.as_str()) {
                    self.started(job);
                }
                self.ui.status.set_label(&stage_text(&stage, done, total));
                let fraction = f64::from(done) / f64::from(total.max(1));
                self.ui.progress.set_fraction(fraction.clamp(0.0, 1.0));
                self.ui.progress.set_visible(stage != "waiting-still");
            }
            Event::Finished { job, path } => {
                if self.session.borrow().job.as_deref() == Some(job.as_str()) {
                    self.ended();
                }
                self.show_result(&path);
            }
            Event::Failed { job, error } => {
                if self.session.borrow().job.as_deref() != Some(job.as_str()) {
                    return;
                }
                self.ended();
                if error == "cancelled" {
                    show_message(&self.ui, &gettext("Cancelled"));
                } else {
                    show_message(
                        &self.ui,
                        &format!("{}: {error}", gettext("The capture failed")),
                    );
                }
            }
        }
    }

    fn show_result(&self, path: &str) {
        match gdk::Texture::from_filename(path) {
            Ok(t) => {
                self.ui.thumbnail_picture.set_paintable(Some(&t));
                self.ui.thumbnail.set_visible(true);
                self.ui
                    .thumbnail
                    .update_property(&[gtk::accessible::Property::Label(&format!(
                        "{} {path}",
                        gettext("Open the picture")
                    ))]);
                self.session.borrow_mut().result = Some(path.to_string());
            }
            Err(e) => show_message(
                &self.ui,
                &format!("{} {path}: {e}", gettext("Cannot show the picture")),
            ),
        }
    }

    /// Lays the window out for its shape; shows the newest frame; starts, renews or restarts
    /// the preview when it is time.
    fn tick(self: &Rc<Self>) {
        let ui = &self.ui;
        let landscape = ui.layout.width() > ui.layout.height();
        if landscape != (ui.layout.orientation() == gtk::Orientation::Horizontal) {
            arrange(&ui.layout, &ui.controls, landscape);
        }
        let mut s = self.session.borrow_mut();
        let look = s.preview.as_mut().map(Preview::look);
        let asked = s.asked;
        let due = |every| asked.is_none_or(|t: Instant| t.elapsed() >= every);
        let ask = match look {
            Some(Look::Frame(texture)) => {
                self.ui.picture.set_paintable(Some(&texture));
                due(RENEW_EVERY)
            }
            Some(Look::Same) => due(RENEW_EVERY),
            Some(Look::Over(state, why)) => {
                s.preview = None;
                if state == State::Failed {
                    let why = why.unwrap_or_else(|| gettext("the camera failed"));
                    show_message(&self.ui, &format!("{}: {why}", gettext("No preview")));
                }
                due(RETRY_EVERY)
            }
            None => due(RETRY_EVERY),
        };
        if !ask || s.asking {
            return;
        }
        s.asking = true;
        drop(s);
        let me = self.clone();
        glib::spawn_future_local(async move {
            let got = me.link.start_preview().await;
            let mut s = me.session.borrow_mut();
            s.asking = false;
            s.asked = Some(Instant::now());
            match got.and_then(|fd| RingReader::new(fd).map_err(|e| e.to_string())) {
                // A renewal hands out the same ring: keep the one mapped.
                Ok(ring) => {
                    if s.preview.is_none() {
                        s.preview = Some(Preview::new(ring));
                        drop(s);
                        if me.session.borrow().job.is_none() {
                            show_message(&me.ui, "");
                        }
                    }
                }
                Err(e) => {
                    drop(s);
                    show_message(&me.ui, &e);
                }
            }
        });
    }
}
