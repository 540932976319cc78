//! The agent's end of chart variables bound to devices (`baton_proto::dist::io`): Zenoh subscriptions for
//! inputs, whose samples become values of the chart, and the text a value is put as for outputs.
//!
//! Payloads are text, as MQTT devices and scripts write them: `true`/`false` (any case, also `TRUE` as ST
//! writes it, and `on`/`off`), integers, reals, IEC literals (`T#2s`, `'text'`), and for a STRING variable any
//! text. A payload that is none of these, for a variable that is not a STRING, is refused by the run, and the
//! variable keeps its value.

use baton_proto::exec::types::Value;
use baton_proto::front::literal::{self, Literal};
use tokio::task::JoinHandle;
use zenoh::Session;

/// The value a payload holds, before the run converts it to its variable's type.
pub fn parse_payload(bytes: &[u8]) -> Value {
    let text = String::from_utf8_lossy(bytes);
    let t = text.trim();
    match t.to_ascii_lowercase().as_str() {
        "true" | "on" => return Value::Bool(true),
        "false" | "off" => return Value::Bool(false),
        _ => {}
    }
    if let Ok(i) = t.parse::<i64>() {
        return Value::Int(i);
    }
    if let Ok(r) = t.parse::<f64>() {
        if r.is_finite() {
            return Value::Real(r);
        }
    }
    match literal::parse(t) {
        Ok(Literal::Scalar(v)) => v,
        Ok(Literal::Text(s)) => Value::Str(s.into()),
        _ => Value::Str(text.into_owned().into()),
    }
}

/// The text an output's value is put as: `true`/`false`, numbers as ST writes them, a TIME in milliseconds, a
/// STRING as it is.
pub fn payload_of(value: &Value) -> String {
    match value {
        Value::Bool(b) => b.to_string(),
        Value::Int(i) | Value::Time(i) => i.to_string(),
        Value::Real(r) => r.to_string(),
        Value::Str(s) => s.to_string(),
    }
}

/// The subscriptions of one run's input bindings; dropped with the run, which undeclares them.
#[derive(Default)]
pub struct Inputs {
    tasks: Vec<JoinHandle<()>>,
}

impl Drop for Inputs {
    fn drop(&mut self) {
        for t in &self.tasks {
            t.abort();
        }
    }
}

impl Inputs {
    /// Subscribes to `key` and hands every sample's value to `deliver`.
    pub fn subscribe(&mut self, session: &Session, key: String, deliver: impl Fn(Value) + Send + 'static) {
        let session = session.clone();
        self.tasks.push(tokio::spawn(async move {
            let subscriber = match session.declare_subscriber(key.clone()).await {
                Ok(s) => s,
                Err(e) => return eprintln!("warning: cannot subscribe to {key}: {e}"),
            };
            while let Ok(sample) = subscriber.recv_async().await {
                deliver(parse_payload(&sample.payload().to_bytes()));
            }
        }));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn payloads_as_devices_write_them() {
        assert_eq!(parse_payload(b"true"), Value::Bool(true));
        assert_eq!(parse_payload(b" OFF\n"), Value::Bool(false));
        assert_eq!(parse_payload(b"TRUE"), Value::Bool(true));
        assert_eq!(parse_payload(b"42"), Value::Int(42));
        assert_eq!(parse_payload(b"-2.5"), Value::Real(-2.5));
        assert_eq!(parse_payload(b"T#1s500ms"), Value::Time(1500));
        assert_eq!(parse_payload(b"'a b'"), Value::Str("a b".to_string().into()));
        assert_eq!(parse_payload(b"hello there"), Value::Str("hello there".to_string().into()));
        assert_eq!(parse_payload(b"NaN"), Value::Str("NaN".to_string().into()));
        assert_eq!(parse_payload(&[0xff, 0xfe]), Value::Str("\u{fffd}\u{fffd}".to_string().into()));
        for v in [Value::Bool(true), Value::Int(-7), Value::Real(0.5), Value::Str("x y".to_string().into())] {
            assert_eq!(parse_payload(payload_of(&v).as_bytes()), v, "{v:?} goes out and comes back the same");
        }
    }
}
