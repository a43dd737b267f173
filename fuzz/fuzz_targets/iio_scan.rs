//! IIO scan-element types (`scan_elements/*_type`) and the buffer records they lay out.
//! Input: up to eight type strings, one per line, then `\0`, then record bytes.
#![no_main]

use focusd::backend::iio::scan::{decode_record, parse_scan_type, Layout};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let (head, record) = match data.iter().position(|&b| b == 0) {
        Some(i) => (&data[..i], &data[i + 1..]),
        None => (data, &[][..]),
    };
    let text = String::from_utf8_lossy(head);
    let channels: Vec<_> = text
        .lines()
        .take(8)
        .enumerate()
        .filter_map(|(i, line)| {
            parse_scan_type(line.trim())
                .ok()
                .map(|t| (format!("ch{i}"), (i as u32 * 7) % 5, t))
        })
        .collect();
    if let Ok(layout) = Layout::new(channels) {
        let _ = decode_record(&layout, record);
        if record.len() >= layout.bytes() {
            let values = decode_record(&layout, &record[..layout.bytes()])
                .expect("a record of the layout's size decodes");
            assert!(values.len() >= layout.elements().len());
        }
    }
});
