//! Calendar dates and times of day in UTC from Unix times, for file names and file metadata.

/// Year, month, day, hour, minute and second of a Unix time, in UTC (Howard Hinnant's
/// civil-from-days).
pub fn utc(secs: u64) -> [u64; 6] {
    let (days, rest) = ((secs / 86_400) as i64, secs % 86_400);
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    [
        year as u64,
        month as u64,
        day as u64,
        rest / 3600,
        rest / 60 % 60,
        rest % 60,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utc_calendar_times() {
        assert_eq!(utc(0), [1970, 1, 1, 0, 0, 0]);
        assert_eq!(utc(951_782_400), [2000, 2, 29, 0, 0, 0]);
        assert_eq!(utc(1_796_083_199), [2026, 11, 30, 23, 59, 59]);
        assert_eq!(utc(4_107_542_400), [2100, 3, 1, 0, 0, 0]);
    }
}
