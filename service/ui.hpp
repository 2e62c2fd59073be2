// UiAssets: the browser page (GET /, /docs and /ui/*), as static files held in memory.
//
// The page's own HTML, CSS and JavaScript are compiled into the server (generated
// ui_assets.hpp, from service/ui/); three.js and its OrbitControls are read once, at
// startup, from Debian's libjs-three (`three_dir`, default /usr/share/javascript/three),
// so the server carries no copy of them. Nothing is fetched at build or run time. When
// three.js is absent the page still loads, and says that it cannot draw without it.
//
// Every answer carries a strict Content-Security-Policy (scripts and styles from this
// origin only, no inline script, no frames, connections only back to this origin): the
// page holds a bearer token while the tab is open, and nothing else may read it.
//
// Thread safety: immutable after load(); find() may be called concurrently.
#pragma once

#include <map>
#include <memory>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace spokemesh::service {

struct UiAsset {
  std::string content_type;
  std::string_view body;  // into the embedded table or `owned_`
};

class UiAssets {
 public:
  // The embedded files plus three.min.js and OrbitControls.js from `three_dir` (absent
  // files are left out and reported by missing()).
  static std::shared_ptr<const UiAssets> load(const std::string& three_dir);

  // The asset at an HTTP path ("/", "/docs", "/ui/app.js", ...), or null.
  const UiAsset* find(std::string_view path) const;
  // Headers every UI answer carries (CSP and friends).
  static const std::vector<std::pair<std::string, std::string>>& security_headers();
  // What could not be read from three_dir ("" when all was found), for the log.
  const std::string& missing() const { return missing_; }
  // Bytes of the page's own files (three.js excluded): the page's budget is 1 MB.
  std::size_t embedded_bytes() const { return embedded_bytes_; }

 private:
  std::map<std::string, UiAsset, std::less<>> by_path_;
  std::vector<std::unique_ptr<std::string>> owned_;
  std::string missing_;
  std::size_t embedded_bytes_ = 0;
};

}  // namespace spokemesh::service
