//! The console's users and what each role may do. A deployment writes the users' file with `baton deploy users`:
//! each user a name, a role and an Argon2id hash of a password the command made up and printed once (PHC strings,
//! as `argon2` writes them). The roles are ordered: a viewer looks; an operator also sends the run's commands,
//! handles alarms and sets inputs; maintenance may also switch to manual mode and `force`, `activate`,
//! `deactivate` and `move`.

use std::path::Path;

use anyhow::{bail, Context};
use argon2::password_hash::rand_core::{OsRng, RngCore};
use argon2::password_hash::{PasswordHash, PasswordHasher, PasswordVerifier, SaltString};
use argon2::Argon2;
use baton_proto::cluster::keys::is_valid_sender;
use baton_proto::cluster::wire::CtlRequest;

#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, serde::Serialize, serde::Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    Viewer,
    Operator,
    Maintenance,
}

impl Role {
    pub fn name(self) -> &'static str {
        match self {
            Role::Viewer => "viewer",
            Role::Operator => "operator",
            Role::Maintenance => "maintenance",
        }
    }
}

/// The role a command needs: manual mode and its changes of the active steps are maintenance's; the rest an
/// operator's.
pub fn needed(request: &CtlRequest) -> Role {
    let command = request.command.to_ascii_lowercase();
    let manual = command == "mode" && request.target.as_deref().is_some_and(|t| t.eq_ignore_ascii_case("manual"));
    if manual || matches!(command.as_str(), "force" | "activate" | "deactivate" | "move") {
        Role::Maintenance
    } else {
        Role::Operator
    }
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
struct UserEntry {
    name: String,
    role: Role,
    /// The password's Argon2id hash, as a PHC string.
    password: String,
}

#[derive(Debug, Default, serde::Serialize, serde::Deserialize)]
struct UsersFile {
    users: Vec<UserEntry>,
}

/// The users a console lets in.
pub struct Users {
    users: Vec<UserEntry>,
    /// A hash checked for a name nobody has, so that a wrong name costs what a wrong password does.
    decoy: String,
}

impl Users {
    /// Reads a users' file, every entry checked: a valid name, once, and a hash that parses.
    pub fn load(path: &Path) -> anyhow::Result<Users> {
        let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
        let file: UsersFile = serde_json::from_str(&text)
            .with_context(|| format!("{}: not a users' file (baton deploy users writes one)", path.display()))?;
        check(&file, path)?;
        if file.users.is_empty() {
            bail!("{}: lists no user: nobody could log in", path.display());
        }
        Ok(Users { users: file.users, decoy: hash("no such user")? })
    }

    /// The role of user `name` if `password` is theirs.
    pub fn check(&self, name: &str, password: &str) -> Option<Role> {
        let entry = self.users.iter().find(|u| u.name == name);
        let stored = entry.map_or(self.decoy.as_str(), |u| u.password.as_str());
        let parsed = PasswordHash::new(stored).ok()?;
        let right = Argon2::default().verify_password(password.as_bytes(), &parsed).is_ok();
        entry.filter(|_| right).map(|u| u.role)
    }
}

fn check(file: &UsersFile, path: &Path) -> anyhow::Result<()> {
    for (i, u) in file.users.iter().enumerate() {
        if !is_valid_sender(&u.name) {
            bail!("{}: `{}` is not a user name (letters, digits, spaces, `-_.@`)", path.display(), u.name);
        }
        if file.users[..i].iter().any(|v| v.name == u.name) {
            bail!("{}: user `{}` is listed twice", path.display(), u.name);
        }
        if PasswordHash::new(&u.password).is_err() {
            bail!("{}: user `{}` has no password hash baton reads", path.display(), u.name);
        }
    }
    Ok(())
}

fn hash(password: &str) -> anyhow::Result<String> {
    let salt = SaltString::generate(&mut OsRng);
    Argon2::default()
        .hash_password(password.as_bytes(), &salt)
        .map(|h| h.to_string())
        .map_err(|e| anyhow::anyhow!("cannot hash a password: {e}"))
}

/// A new password: 20 characters of an alphabet without look-alikes (0/O, 1/l/I), about 116 bits.
fn new_password() -> String {
    const ALPHABET: &[u8] = b"abcdefghijkmnpqrstuvwxyzABCDEFGHJKLMNPQRSTUVWXYZ23456789";
    let mut out = String::new();
    let mut byte = [0u8; 1];
    while out.len() < 20 {
        OsRng.fill_bytes(&mut byte);
        // Bytes past the last whole multiple of the alphabet are drawn again: every character equally likely.
        if usize::from(byte[0]) < ALPHABET.len() * (256 / ALPHABET.len()) {
            out.push(char::from(ALPHABET[usize::from(byte[0]) % ALPHABET.len()]));
        }
    }
    out
}

/// `baton deploy users FILE NAME=ROLE…`: adds each user (or gives one already there a new password and this role)
/// and removes those in `remove`; the others stay as they were. The file is written readable by its owner only.
/// Returns each added user's new password, to be handed over once: the file keeps only its hash.
pub fn write(path: &Path, add: &[(String, Role)], remove: &[String]) -> anyhow::Result<Vec<(String, Role, String)>> {
    let mut file: UsersFile = match std::fs::read_to_string(path) {
        Ok(text) => serde_json::from_str(&text).with_context(|| format!("{}: not a users' file", path.display()))?,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => UsersFile::default(),
        Err(e) => return Err(e).with_context(|| format!("cannot read {}", path.display())),
    };
    file.users.retain(|u| !remove.contains(&u.name) && !add.iter().any(|(n, _)| n == &u.name));
    let mut made = Vec::new();
    for (name, role) in add {
        if !is_valid_sender(name) {
            bail!("`{name}` is not a user name (letters, digits, spaces, `-_.@`)");
        }
        let password = new_password();
        file.users.push(UserEntry { name: name.clone(), role: *role, password: hash(&password)? });
        made.push((name.clone(), *role, password));
    }
    check(&file, path)?;
    let text = serde_json::to_string_pretty(&file).context("the users' file")? + "\n";
    write_private(path, &text)?;
    Ok(made)
}

/// Writes `text` to `path` through a file of mode 0600 renamed over it: never readable by others, never half
/// written.
fn write_private(path: &Path, text: &str) -> anyhow::Result<()> {
    use std::io::Write;
    use std::os::unix::fs::OpenOptionsExt;
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let staged = dir.join(format!(".{}.new", path.file_name().and_then(|n| n.to_str()).unwrap_or("users")));
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(true)
        .mode(0o600)
        .open(&staged)
        .with_context(|| format!("cannot write {}", staged.display()))?;
    f.write_all(text.as_bytes())
        .and_then(|()| f.sync_all())
        .with_context(|| format!("cannot write {}", staged.display()))?;
    std::fs::rename(&staged, path).with_context(|| format!("cannot write {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ctl(command: &str, target: Option<&str>) -> CtlRequest {
        CtlRequest {
            command: command.into(),
            target: target.map(str::to_string),
            agent: None,
            step: None,
            for_ms: None,
            to: None,
            reason: String::new(),
            by: String::new(),
            user: None,
        }
    }

    #[test]
    fn manual_mode_and_its_changes_are_maintenances_the_rest_an_operators() {
        for (command, target) in
            [("force", Some("T1")), ("activate", Some("S")), ("move", Some("S")), ("mode", Some("MANUAL"))]
        {
            assert_eq!(needed(&ctl(command, target)), Role::Maintenance, "{command}");
        }
        for (command, target) in [("hold", None), ("mode", Some("step")), ("confirm", None), ("ack", Some("3"))] {
            assert_eq!(needed(&ctl(command, target)), Role::Operator, "{command}");
        }
        assert!(Role::Viewer < Role::Operator && Role::Operator < Role::Maintenance);
    }

    #[test]
    fn a_written_file_lets_its_users_in_with_their_passwords_only() {
        let dir = tempfile::tempdir().expect("dir");
        let path = dir.path().join("users.json");
        let made = write(&path, &[("anna".into(), Role::Operator), ("bob".into(), Role::Viewer)], &[]).expect("write");
        let mode = std::os::unix::fs::PermissionsExt::mode(&std::fs::metadata(&path).expect("meta").permissions());
        assert_eq!(mode & 0o777, 0o600);
        let text = std::fs::read_to_string(&path).expect("read");
        assert!(made.iter().all(|(_, _, p)| p.len() == 20 && !text.contains(p.as_str())), "no password in the file");
        let users = Users::load(&path).expect("load");
        let (anna, bob) = (&made[0].2, &made[1].2);
        assert_eq!(users.check("anna", anna), Some(Role::Operator));
        assert_eq!(users.check("bob", bob), Some(Role::Viewer));
        assert_eq!(users.check("anna", bob), None);
        assert_eq!(users.check("nobody", anna), None);
        // Anna again: a new password and role; bob removed; the first password no longer works.
        let again = write(&path, &[("anna".into(), Role::Maintenance)], &["bob".into()]).expect("rewrite");
        let users = Users::load(&path).expect("load");
        assert_eq!(users.check("anna", &again[0].2), Some(Role::Maintenance));
        assert_eq!(users.check("anna", anna), None);
        assert_eq!(users.check("bob", bob), None);
        assert!(write(&path, &[("a/b".into(), Role::Viewer)], &[]).is_err());
        std::fs::write(&path, r#"{"users": [{"name": "x", "role": "viewer", "password": "plain"}]}"#).expect("w");
        assert!(Users::load(&path).is_err_and(|e| e.to_string().contains("no password hash")));
    }
}
