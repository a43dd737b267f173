//! Who is calling: each caller's uid, asked of the bus once per connection and kept.
//!
//! The service handles one call at a time (see `interface`), so a client's flood of pipelined
//! calls waits in the bus, under the bus's limits, not in the service; a kept uid makes each of
//! those calls cheap. Unique names are never reused on a bus, so a kept uid cannot pass to
//! another connection; the table is bounded, and what falls out of it is only asked again.

use super::interface::FocusdError;
use std::collections::HashMap;
use std::sync::Mutex;
use zbus::message::Header;

/// Connections whose uid is kept; when full, the table starts again.
const KEPT: usize = 1024;

pub struct Callers {
    known: Mutex<HashMap<String, u32>>,
    /// A connection of its own for asking the bus: on the service's connection the answer
    /// would queue behind the very call that is waiting for it.
    bus: zbus::Connection,
}

impl Callers {
    pub fn new(bus: zbus::Connection) -> Callers {
        Callers {
            known: Mutex::default(),
            bus,
        }
    }

    /// The uid of a method call's sender: kept, or asked of the bus.
    pub async fn uid(&self, header: &Header<'_>) -> Result<u32, FocusdError> {
        let sender = header
            .sender()
            .ok_or_else(|| FocusdError::AccessDenied("the call names no sender".into()))?;
        if let Some(uid) = self.lock().get(sender.as_str()) {
            return Ok(*uid);
        }
        let uid = async {
            zbus::fdo::DBusProxy::new(&self.bus)
                .await?
                .get_connection_unix_user(sender.clone().into())
                .await
        }
        .await
        .map_err(|e| FocusdError::AccessDenied(format!("cannot tell who {sender} is: {e}")))?;
        keep(&mut self.lock(), sender.as_str(), uid);
        Ok(uid)
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<String, u32>> {
        self.known.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// Keeps `name`'s uid, within [`KEPT`] names.
fn keep(known: &mut HashMap<String, u32>, name: &str, uid: u32) {
    if known.len() >= KEPT {
        known.clear();
    }
    known.insert(name.to_string(), uid);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_table_stays_bounded_and_keeps_the_newest() {
        let mut known = HashMap::new();
        for i in 0..3 * KEPT {
            keep(&mut known, &format!(":1.{i}"), i as u32);
            assert!(known.len() <= KEPT);
        }
        let last = format!(":1.{}", 3 * KEPT - 1);
        assert_eq!(known.get(&last), Some(&(3 * KEPT as u32 - 1)));
    }
}
