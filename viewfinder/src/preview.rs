//! The preview on screen: the daemon's ring read at the display's pace, each new frame handed
//! to GTK as a memory texture in the ring's own format (RGB8, no conversion).

use focusd::service::preview::ring::{RingReader, State};
use gtk::{gdk, glib};

/// A mapped ring and the last frame shown from it.
pub struct Preview {
    ring: RingReader,
    shown: u64,
}

/// What a look at the ring found.
pub enum Look {
    /// A frame newer than the last one shown.
    Frame(gdk::MemoryTexture),
    /// Nothing new; the preview is still on.
    Same,
    /// The ring gets no more frames (stopped, or failed and why): start a new preview.
    Over(State, Option<String>),
}

impl Preview {
    pub fn new(ring: RingReader) -> Preview {
        Preview { ring, shown: 0 }
    }

    pub fn look(&mut self) -> Look {
        let state = self.ring.state().unwrap_or(State::Failed);
        if matches!(state, State::Stopped | State::Failed) {
            return Look::Over(state, self.ring.error());
        }
        if self.ring.sequence() == self.shown {
            return Look::Same;
        }
        match self.ring.latest() {
            Some(f) => {
                self.shown = f.sequence;
                Look::Frame(gdk::MemoryTexture::new(
                    f.width as i32,
                    f.height as i32,
                    gdk::MemoryFormat::R8g8b8,
                    &glib::Bytes::from_owned(f.pixels),
                    f.stride as usize,
                ))
            }
            None => Look::Same,
        }
    }
}
