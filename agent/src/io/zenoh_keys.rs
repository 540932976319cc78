//! Variables bound to Zenoh keys: a subscription for an input, whose samples become values of the chart, and a
//! publisher for an output, which puts its values as text at every change (and again every `period_ms`).
//!
//! Payloads are text, as MQTT devices and scripts write them: `true`/`false` (any case, also `TRUE` as ST
//! writes it, and `on`/`off`), integers, reals, IEC literals (`T#2s`, `'text'`), and for a STRING variable any
//! text. A payload that is none of these, for a variable that is not a STRING, is refused by the run, and the
//! variable keeps its value.

use std::sync::Arc;

use baton_proto::cluster::bindings::IoBinding;
use baton_proto::front::literal::{self, Literal};
use baton_proto::types::Value;
use zenoh::qos::CongestionControl;
use zenoh::Session;

use super::shared::{Latest, Resend, Sink};

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

/// Subscribes to an input's key expression and hands every sample's value to the run.
pub async fn input(session: Session, binding: usize, b: IoBinding, sink: Sink) {
    let key = b.key().unwrap_or_default().to_string();
    let subscriber = match baton_host::traffic::subscriber(&session, key.clone()).await {
        Ok(s) => s,
        Err(e) => return sink.state(binding, Err(format!("cannot subscribe to {key}: {e}"))),
    };
    while let Ok(sample) = subscriber.recv_async().await {
        sink.value(binding, parse_payload(&sample.payload().to_bytes()));
    }
}

/// Puts an output's values on its key, the latest when the last put is done.
pub async fn output(session: Session, binding: usize, b: IoBinding, latest: Arc<Latest>, sink: Sink) {
    let key = b.key().unwrap_or_default().to_string();
    let publisher = match baton_host::traffic::publisher(&session, key.clone())
        .congestion_control(CongestionControl::Block)
        .await
    {
        Ok(p) => p,
        Err(e) => return sink.state(binding, Err(format!("cannot publish on {key}: {e}"))),
    };
    let mut down = false;
    let mut resend = Resend::new(binding, b.period_ms());
    loop {
        let value = resend.next(&latest).await;
        match publisher.put(payload_of(&value)).await {
            Ok(()) if std::mem::take(&mut down) => sink.state(binding, Ok(())),
            Ok(()) => {}
            Err(e) => {
                down = true;
                sink.state(binding, Err(format!("cannot publish on {key}: {e}")));
            }
        }
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
