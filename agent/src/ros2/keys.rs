//! rmw_zenoh's key expressions, in one place: the data key of a topic or a service
//! (`<domain>/<name>/<dds type>/<type hash>`), the liveliness tokens of the ROS graph
//! (`@ros2_lv/<domain>/<zid>/<node>/<entity>/<kind>/<enclave>/<namespace>/<node name>[/<name>/<type>/<hash>/<qos>]`)
//! and the attachment of every request and publication (sequence number, source time, source GID).

use super::interfaces::WireType;

const ADMIN_SPACE: &str = "@ros2_lv";
/// QoS of a service or a client as rmw_zenoh encodes it: reliable, volatile, keep last 10.
pub const SERVICE_QOS: &str = "::,10:,:,:,,";
/// QoS of a default subscription or publication (keep last 10), as `ros2 topic` makes them.
pub const TOPIC_QOS: &str = "::,10:,:,:,,";

/// A graph entity's kind, as its liveliness token spells it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    Node,
    Publisher,
    Subscription,
    Service,
    Client,
}

impl Kind {
    fn tag(self) -> &'static str {
        match self {
            Kind::Node => "NN",
            Kind::Publisher => "MP",
            Kind::Subscription => "MS",
            Kind::Service => "SS",
            Kind::Client => "SC",
        }
    }
}

/// A ROS name in a liveliness token: `/` becomes `%`.
fn mangle(name: &str) -> String {
    name.replace('/', "%")
}

/// A topic or service name as rmw_zenoh keys it: no leading or trailing `/`.
fn strip(name: &str) -> &str {
    name.trim_matches('/')
}

/// The key a service answers on or a topic is published on.
pub fn data(domain: u32, name: &str, wire: &WireType) -> String {
    format!("{domain}/{}/{}/{}", strip(name), wire.dds_name, wire.hash)
}

/// Who the agent is in the ROS graph.
#[derive(Clone, Debug)]
pub struct NodeId {
    pub domain: u32,
    pub zid: String,
    pub id: u32,
    pub namespace: String,
    pub name: String,
}

impl NodeId {
    fn prefix(&self, entity: u32, kind: Kind) -> String {
        let namespace =
            if self.namespace.is_empty() || self.namespace == "/" { "%".to_string() } else { mangle(&self.namespace) };
        format!(
            "{ADMIN_SPACE}/{}/{}/{}/{entity}/{}/%/{namespace}/{}",
            self.domain,
            self.zid,
            self.id,
            kind.tag(),
            mangle(&self.name)
        )
    }

    /// The node's own token.
    pub fn token(&self) -> String {
        self.prefix(self.id, Kind::Node)
    }

    /// An endpoint's token: a client, a subscription…
    pub fn endpoint_token(&self, entity: u32, kind: Kind, name: &str, wire: &WireType, qos: &str) -> String {
        let name = format!("/{}", strip(name));
        format!("{}/{}/{}/{}/{qos}", self.prefix(entity, kind), mangle(&name), wire.dds_name, wire.hash)
    }
}

/// The tokens of every server of `kind` (`Service`, `Publisher`…) for `name` on `domain`, whatever their type:
/// a server of another type is found too, so the agent can say why it does not answer.
pub fn servers(domain: u32, kind: Kind, name: &str) -> String {
    let name = format!("/{}", strip(name));
    format!("{ADMIN_SPACE}/{domain}/*/*/*/{}/*/*/*/{}/*/*/*", kind.tag(), mangle(&name))
}

/// The type a server's token announces: its DDS name and hash.
pub fn announced_type(token: &str) -> Option<WireType> {
    let parts: Vec<&str> = token.split('/').collect();
    // admin, domain, zid, node, entity, kind, enclave, namespace, node name, name, type, hash, qos
    (parts.len() == 13).then(|| WireType { dds_name: parts[10].to_string(), hash: parts[11].to_string() })
}

/// The attachment rmw_zenoh puts on a request or a publication: sequence number and source time (little-endian
/// i64), then the source GID with its length.
pub fn attachment(sequence: i64, time_ns: i64, gid: &[u8; 16]) -> Vec<u8> {
    let mut out = Vec::with_capacity(33);
    out.extend_from_slice(&sequence.to_le_bytes());
    out.extend_from_slice(&time_ns.to_le_bytes());
    out.push(16);
    out.extend_from_slice(gid);
    out
}

/// The sequence number and GID of an attachment, if it is one.
pub fn read_attachment(bytes: &[u8]) -> Option<(i64, [u8; 16])> {
    if bytes.len() < 33 || bytes[16] != 16 {
        return None;
    }
    let sequence = i64::from_le_bytes(bytes[..8].try_into().ok()?);
    Some((sequence, bytes[17..33].try_into().ok()?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_are_spelt_as_rmw_zenoh_spells_them() {
        let wire = WireType { dds_name: "std_srvs::srv::dds_::SetBool_".into(), hash: "RIHS01_ab".into() };
        assert_eq!(data(0, "/gripper/close", &wire), "0/gripper/close/std_srvs::srv::dds_::SetBool_/RIHS01_ab");
        let node = NodeId { domain: 3, zid: "1f2e".into(), id: 0, namespace: "/".into(), name: "baton_cell1".into() };
        assert_eq!(node.token(), "@ros2_lv/3/1f2e/0/0/NN/%/%/baton_cell1");
        let client = node.endpoint_token(4, Kind::Client, "/gripper/close", &wire, SERVICE_QOS);
        assert_eq!(
            client,
            "@ros2_lv/3/1f2e/0/4/SC/%/%/baton_cell1/%gripper%close/std_srvs::srv::dds_::SetBool_/RIHS01_ab/::,10:,:,:,,"
        );
        assert_eq!(announced_type(&client), Some(wire));
        assert_eq!(servers(3, Kind::Service, "gripper/close"), "@ros2_lv/3/*/*/*/SS/*/*/*/%gripper%close/*/*/*");
        let att = attachment(7, 99, &[5; 16]);
        assert_eq!(att.len(), 33);
        assert_eq!(read_attachment(&att), Some((7, [5; 16])));
        assert_eq!(read_attachment(&att[..20]), None);
    }
}
