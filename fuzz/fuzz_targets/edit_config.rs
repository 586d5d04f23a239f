//! The edit TOML config and `--set KEY=VALUE` overrides: never panic; an accepted
//! config is valid and survives a TOML write + read.
#![no_main]

use libfuzzer_sys::fuzz_target;
use transsplat_edit::EditConfig;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    if let Ok(c) = EditConfig::from_toml(text) {
        c.validate().expect("accepted config is valid");
        let back = EditConfig::from_toml(&c.to_toml()).expect("a config we wrote reads back");
        assert_eq!(back, c);
    }
    // Each line as one --set override on the defaults.
    let sets: Vec<String> = text.lines().map(str::to_string).collect();
    if let Ok(c) = EditConfig::default().with_overrides(&sets) {
        c.validate().expect("accepted overrides are valid");
        let back = EditConfig::from_toml(&c.to_toml()).expect("a config we wrote reads back");
        assert_eq!(back, c);
    }
});
